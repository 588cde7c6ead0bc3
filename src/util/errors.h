#pragma once
// Error types shared by every module.
//
// InputError is what bad user input raises: the CLI prints its one-line message
// ("FILE: FIELD: what is wrong") and exits with code 2. Anything else that escapes
// is an internal error (exit code 1).
#include <stdexcept>
#include <string>

namespace ablenerf {

class InputError : public std::runtime_error {
 public:
  InputError(const std::string& file, const std::string& field, const std::string& what)
      : std::runtime_error(compose(file, field, what)), file_(file), field_(field) {}
  const std::string& file() const { return file_; }
  const std::string& field() const { return field_; }

 private:
  static std::string compose(const std::string& file, const std::string& field,
                             const std::string& what) {
    std::string s = file.empty() ? std::string("<input>") : file;
    if (!field.empty()) s += ": " + field;
    return s + ": " + what;
  }
  std::string file_, field_;
};

// Exit codes of the CLI.
constexpr int kExitOk = 0;
constexpr int kExitInternal = 1;
constexpr int kExitBadInput = 2;
constexpr int kExitInterrupted = 130;

}  // namespace ablenerf
