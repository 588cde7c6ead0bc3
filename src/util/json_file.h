#pragma once
// JSON read from a file or a file's text, or one InputError naming the file: where the text stopped
// parsing ("FILE: byte N: invalid JSON"), or what nlohmann rejected in it (a number too large for a
// double), with an optional hint after "invalid JSON" (what the user can do about it).
#include <nlohmann/json.hpp>

#include <string>

namespace ablenerf {

// `text` as JSON; `origin` names the file it came from in the error.
nlohmann::json parse_json_text(const std::string& text, const std::string& origin, const std::string& hint = "");
// The whole file at `path` as JSON (util/fs.h's read_file, then parse_json_text).
nlohmann::json read_json_file(const std::string& path, const std::string& hint = "");

}  // namespace ablenerf
