#pragma once
// What every section of the run configuration is made of, and how a module registers one. A section
// is a plain struct owned by the module that reads it (model/model_config.h, model/compute_config.h,
// data/data_config.h, train/train_config.h, eval/eval_config.h) with
//   static constexpr const char* kName: its name in config.toml ("train");
//   static constexpr int kOrder: its place among the sections when config.toml is written;
//   template <class F> void visit(F&& f): f("key", &field) for each of its keys, once, in the order
//     config.toml lists them (int, int64_t, double, bool, or an enum with an EnumNames table);
//   void validate(const SectionCheck& need) const: need(ok, "key", "what is wrong") per rule;
// and its header registers it with ABLENERF_CONFIG_SECTION(Type). util/config.h's Config then
// holds one of it, reads and writes its keys, and hands it out as config.get<Type>(). Section
// headers include only this file, so no module includes one above it to name its settings.
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <type_traits>
#include <typeindex>
#include <utility>
#include <variant>
#include <vector>

namespace ablenerf {

// The names of an enum's values, one table per enum (config files, --set, logs, bench reports),
// specialised next to the enum in its section's header.
template <class E>
using EnumNames = std::vector<std::pair<E, const char*>>;
template <class E>
inline const EnumNames<E> kEnumNames;

template <class E>
const EnumNames<E>& enum_names() {
  static_assert(std::is_enum_v<E>, "enum_names: not an enum");
  return kEnumNames<E>;
}
template <class E>
const char* name_of(E value) {
  for (const auto& [v, n] : enum_names<E>())
    if (v == value) return n;
  return "?";
}
template <class E>
std::optional<E> enum_from_name(const std::string& name) {
  for (const auto& [v, n] : enum_names<E>())
    if (name == n) return v;
  return std::nullopt;
}

// A section's validate() calls need(ok, key, what) for every rule; the config turns a failed rule
// into InputError(file, "section.key", what).
using SectionCheck = std::function<void(bool ok, const char* key, const std::string& what)>;

namespace config_detail {

// One key of a section as the config's reader and writer see it: a plain field, or an enum seen
// through its name table.
struct EnumField {
  std::function<const char*()> get;
  std::function<bool(const std::string&)> set;  // false for a name the table lacks
  std::string allowed;                          // must be "a", "b" or "c"
};
using Field = std::variant<int*, int64_t*, double*, bool*, EnumField>;
using FieldVisitor = std::function<void(const char* key, Field field)>;

template <class E>
std::string allowed_names() {
  std::string s;
  const auto& t = enum_names<E>();
  for (size_t i = 0; i < t.size(); ++i)
    s += std::string(i == 0 ? "" : (i + 1 == t.size() ? " or " : ", ")) + "\"" + t[i].second + "\"";
  return "must be " + s;
}

template <class T>
Field field(T* p) {
  if constexpr (std::is_enum_v<T>) {
    return EnumField{[p] { return name_of(*p); },
                     [p](const std::string& name) {
                       const auto v = enum_from_name<T>(name);
                       if (v) *p = *v;
                       return v.has_value();
                     },
                     allowed_names<T>()};
  } else {
    return Field(p);
  }
}

// A registered section type, erased.
struct SectionType {
  std::type_index type;
  const char* name;
  int order;
  std::function<std::shared_ptr<void>()> make;                     // its defaults
  std::function<std::shared_ptr<void>(const void*)> copy;          // a deep copy
  std::function<void(void*, const FieldVisitor&)> visit;           // its keys
  std::function<void(const void*, const SectionCheck&)> validate;  // its rules
};

// Every registered section, by order (inline, so that a section header needs no library to
// register itself: programs that read no config, like the kernels' tests, may include one).
inline std::vector<std::shared_ptr<const SectionType>>& section_registry() {
  static std::vector<std::shared_ptr<const SectionType>> r;
  return r;
}
inline const std::vector<std::shared_ptr<const SectionType>>& sections() { return section_registry(); }

// Adds a section type in its order (once per type; a second registration of the same type is ignored).
inline bool register_section(SectionType section) {
  auto& r = section_registry();
  for (const auto& t : r)
    if (t->type == section.type) return true;
  auto at = r.begin();
  while (at != r.end() && (*at)->order <= section.order) ++at;
  r.insert(at, std::make_shared<const SectionType>(std::move(section)));
  return true;
}

// A section held by a Config: its type and its values.
struct SectionSlot {
  std::shared_ptr<const SectionType> type;
  std::shared_ptr<void> data;
};

template <class S>
bool register_section_type() {
  return register_section(
      SectionType{std::type_index(typeid(S)), S::kName, S::kOrder, [] { return std::make_shared<S>(); },
                  [](const void* p) { return std::make_shared<S>(*static_cast<const S*>(p)); },
                  [](void* p, const FieldVisitor& f) {
                    static_cast<S*>(p)->visit([&](const char* key, auto* field_ptr) { f(key, field(field_ptr)); });
                  },
                  [](const void* p, const SectionCheck& need) { static_cast<const S*>(p)->validate(need); }});
}

}  // namespace config_detail

// In a section's header, after the struct: every program that includes the header knows the section.
#define ABLENERF_CONFIG_SECTION(Type) \
  inline const bool kConfigSectionRegistered_##Type = ::ablenerf::config_detail::register_section_type<Type>()

}  // namespace ablenerf
