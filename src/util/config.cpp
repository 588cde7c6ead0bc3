#include "util/config.h"

#define TOML_HEADER_ONLY 1
#define TOML_EXCEPTIONS 1
#include <toml++/toml.h>

#include <cmath>
#include <functional>
#include <map>
#include <sstream>
#include <variant>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

using config_detail::EnumField;
using config_detail::Field;

using config_detail::SectionSlot;
using config_detail::SectionType;
using Sections = std::vector<SectionSlot>;

// Every key of every section, once: f("section.key", field). (items() reads the fields through the
// same visitor that writes them.)
template <typename F>
void visit_fields(const Sections& sections, F&& f) {
  for (const auto& s : sections)
    s.type->visit(s.data.get(),
                  [&](const char* key, Field field) { f(std::string(s.type->name) + "." + key, std::move(field)); });
}

std::string format_double(double v) {
  std::ostringstream ss;
  ss.precision(17);
  ss << v;
  std::string s = ss.str();
  if (s.find_first_of(".eEn") == std::string::npos) s += ".0";
  return s;
}

std::string value_string(const Field& ref) {
  return std::visit(
      [](const auto& p) -> std::string {
        using P = std::decay_t<decltype(p)>;
        if constexpr (std::is_same_v<P, EnumField>) {
          return std::string("\"") + p.get() + "\"";
        } else {
          using T = std::remove_pointer_t<P>;
          if constexpr (std::is_same_v<T, bool>)
            return *p ? "true" : "false";
          else if constexpr (std::is_same_v<T, double>)
            return format_double(*p);
          else
            return std::to_string(*p);
        }
      },
      ref);
}

// Sets a field from a TOML node; throws InputError on a type mismatch.
void set_from_node(const Field& ref, const toml::node& node, const std::string& file, const std::string& key) {
  std::visit(
      [&](const auto& p) {
        using P = std::decay_t<decltype(p)>;
        if constexpr (std::is_same_v<P, EnumField>) {
          if (!node.is_string() || !p.set(node.as_string()->get())) throw InputError(file, key, p.allowed);
          return;
        } else {
          using T = std::remove_pointer_t<P>;
          if constexpr (std::is_same_v<T, bool>) {
            if (!node.is_boolean()) throw InputError(file, key, "expected true or false");
            *p = node.as_boolean()->get();
          } else if constexpr (std::is_same_v<T, double>) {
            if (node.is_floating_point())
              *p = node.as_floating_point()->get();
            else if (node.is_integer())
              *p = static_cast<double>(node.as_integer()->get());
            else
              throw InputError(file, key, "expected a number");
            if (!std::isfinite(*p)) throw InputError(file, key, "must be finite");
          } else {
            if (!node.is_integer()) throw InputError(file, key, "expected an integer");
            const int64_t v = node.as_integer()->get();
            if constexpr (std::is_same_v<T, int>) {
              if (v < INT32_MIN || v > INT32_MAX) throw InputError(file, key, "out of range");
            }
            *p = static_cast<T>(v);
          }
        }
      },
      ref);
}

std::map<std::string, Field> field_map(const Sections& sections) {
  std::map<std::string, Field> m;
  visit_fields(sections, [&](const std::string& k, Field f) { m.emplace(k, std::move(f)); });
  return m;
}

void apply_table(const Sections& sections, const toml::table& tbl, const std::string& file) {
  auto fields = field_map(sections);
  for (const auto& [section, node] : tbl) {
    const std::string sec(section.str());
    const toml::table* st = node.as_table();
    if (!st) throw InputError(file, sec, "expected a [" + sec + "] table");
    for (const auto& [k, v] : *st) {
      const std::string key = sec + "." + std::string(k.str());
      auto it = fields.find(key);
      if (it == fields.end()) throw InputError(file, key, "unknown key");
      set_from_node(it->second, v, file, key);
    }
  }
}

}  // namespace

Config::Config() {
  for (const auto& t : config_detail::sections()) sections_.push_back({t, t->make()});
}

Config::Config(const Config& other) : source(other.source) {
  for (const auto& s : other.sections_) sections_.push_back({s.type, s.type->copy(s.data.get())});
}

Config& Config::operator=(const Config& other) {
  if (this != &other) *this = Config(other);
  return *this;
}

void* Config::find(std::type_index type) const {
  for (const auto& s : sections_)
    if (s.type->type == type) return s.data.get();
  throw std::logic_error(std::string("Config: no registered section of type ") + type.name());
}

Config Config::parse(const std::string& text, const std::string& origin) {
  Config c;
  c.source = origin;
  toml::table tbl;
  try {
    tbl = toml::parse(std::string_view(text), std::string_view(origin));
  } catch (const toml::parse_error& e) {
    const auto& b = e.source().begin;
    throw InputError(origin, "line " + std::to_string(b.line), "invalid TOML: " + std::string(e.description()));
  }
  apply_table(c.sections_, tbl, origin);
  return c;
}

Config Config::load(const std::string& path) { return parse(read_file(path), path); }

void Config::set(const std::string& assignment) {
  const auto eq = assignment.find('=');
  if (eq == std::string::npos || eq == 0) throw InputError("--set", assignment, "expected section.key=value");
  const std::string key = assignment.substr(0, eq), value = assignment.substr(eq + 1);
  auto fields = field_map(sections_);
  auto it = fields.find(key);
  if (it == fields.end()) throw InputError("--set", key, "unknown key");
  // Names may be given bare (--set data.background=black).
  const bool is_string = std::holds_alternative<EnumField>(it->second);
  std::string doc = "v = " + ((is_string && (value.empty() || value[0] != '"')) ? "\"" + value + "\"" : value);
  toml::table tbl;
  try {
    tbl = toml::parse(std::string_view(doc), std::string_view("--set"));
  } catch (const toml::parse_error&) {
    throw InputError("--set", key, "cannot parse value '" + value + "'");
  }
  set_from_node(it->second, *tbl.get("v"), "--set", key);
}

void Config::validate() const {
  for (const auto& s : sections_)
    s.type->validate(s.data.get(), [&](bool ok, const char* key, const std::string& what) {
      if (!ok) throw InputError(source, std::string(s.type->name) + "." + key, what);
    });
}

std::vector<std::pair<std::string, std::string>> Config::items() const {
  std::vector<std::pair<std::string, std::string>> out;
  visit_fields(sections_, [&](const std::string& k, const Field& ref) { out.emplace_back(k, value_string(ref)); });
  return out;
}

std::string Config::to_toml() const {
  std::string out, section;
  for (const auto& [key, value] : items()) {
    const auto dot = key.find('.');
    const std::string sec = key.substr(0, dot);
    if (sec != section) {
      out += (section.empty() ? "" : "\n") + ("[" + sec + "]\n");
      section = sec;
    }
    out += key.substr(dot + 1) + " = " + value + "\n";
  }
  return out;
}

}  // namespace ablenerf
