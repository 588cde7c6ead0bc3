#pragma once
// Run configuration: one schema, enforced. Every key lives in exactly one place, the section of the
// module that reads it (util/config_section.h: [model] model/model_config.h, [compute]
// model/compute_config.h, [data] data/data_config.h, [train] train/train_config.h, [eval]
// eval/eval_config.h), is read from TOML, can be overridden as `--set section.key=value`, and is
// written back as the run's resolved config. Unknown keys are errors. A Config holds one of every
// section registered in the program, at its defaults until read; code reads its own with
// config.get<TrainConfig>().
#include <memory>
#include <stdexcept>
#include <string>
#include <typeindex>
#include <utility>
#include <vector>

#include "util/config_section.h"

namespace ablenerf {

class Config {
 public:
  Config();  // every registered section at its defaults
  Config(const Config& other);
  Config& operator=(const Config& other);
  Config(Config&&) noexcept = default;
  Config& operator=(Config&&) noexcept = default;

  // The section of type S (its header registers it, so any code that names S has it).
  template <class S>
  S& get() {
    return *static_cast<S*>(find(std::type_index(typeid(S))));
  }
  template <class S>
  const S& get() const {
    return *static_cast<const S*>(find(std::type_index(typeid(S))));
  }

  std::string source = "<defaults>";  // where it came from, for error messages

  // Loads a TOML file over the defaults. Throws InputError(file, key, ...) on any problem.
  static Config load(const std::string& toml_path);
  // Parses TOML text (`origin` names it in errors).
  static Config parse(const std::string& toml_text, const std::string& origin);
  // Applies "section.key=value"; throws InputError("--set", key, ...).
  void set(const std::string& assignment);
  // Checks ranges and consistency; throws InputError(source, key, ...).
  void validate() const;
  // The full resolved config as TOML text (every key).
  std::string to_toml() const;
  // All keys with their current values as strings, in schema order.
  std::vector<std::pair<std::string, std::string>> items() const;

 private:
  void* find(std::type_index type) const;  // std::logic_error when the type is not a registered section
  // One per registered section, in their order.
  std::vector<config_detail::SectionSlot> sections_;
};

}  // namespace ablenerf
