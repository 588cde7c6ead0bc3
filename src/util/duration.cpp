#include "util/duration.h"

#include <cctype>
#include <cmath>
#include <cstdlib>

namespace ablenerf {

std::optional<double> parse_duration(const std::string& text) {
  if (text.empty()) return std::nullopt;
  double total = 0;
  size_t i = 0;
  bool had_unit = false;
  while (i < text.size()) {
    const char* begin = text.c_str() + i;
    if (!std::isdigit(static_cast<unsigned char>(*begin)) && *begin != '.') return std::nullopt;
    char* end = nullptr;
    const double v = std::strtod(begin, &end);
    if (end == begin || !std::isfinite(v)) return std::nullopt;
    i = static_cast<size_t>(end - text.c_str());
    if (i == text.size()) {
      if (had_unit) return std::nullopt;  // "1h30" is ambiguous
      return v;
    }
    double unit = 0;
    switch (text[i]) {
      case 's': unit = 1; break;
      case 'm': unit = 60; break;
      case 'h': unit = 3600; break;
      default: return std::nullopt;
    }
    total += v * unit;
    had_unit = true;
    ++i;
  }
  return total;
}

}  // namespace ablenerf
