#pragma once
// Durations as people write them on a command line: "90s", "5m", "2h", "1h30m", "1.5h", or a
// bare number of seconds ("300").
#include <optional>
#include <string>

namespace ablenerf {

// Seconds in `text`, or nothing when it is not a duration (empty, negative, unknown unit, a unit
// without a number, a bare number after a unit).
std::optional<double> parse_duration(const std::string& text);

}  // namespace ablenerf
