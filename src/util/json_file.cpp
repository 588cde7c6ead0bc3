#include "util/json_file.h"

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

nlohmann::json parse_json_text(const std::string& text, const std::string& origin, const std::string& hint) {
  try {
    return nlohmann::json::parse(text);
  } catch (const nlohmann::json::parse_error& e) {
    throw InputError(origin, "byte " + std::to_string(e.byte), "invalid JSON" + hint);
  } catch (const nlohmann::json::exception& e) {
    // e.g. a number too large for a double (1e999): nlohmann reports it as out_of_range.
    throw InputError(origin, "", std::string("invalid JSON (") + e.what() + ")" + hint);
  }
}

nlohmann::json read_json_file(const std::string& path, const std::string& hint) {
  return parse_json_text(read_file(path), path, hint);
}

}  // namespace ablenerf
