// Durations from the command line (--time-budget): units, combinations and what is refused.
#include <gtest/gtest.h>

#include "util/duration.h"

using ablenerf::parse_duration;

TEST(Duration, UnitsAndCombinations) {
  EXPECT_DOUBLE_EQ(*parse_duration("90s"), 90.0);
  EXPECT_DOUBLE_EQ(*parse_duration("5m"), 300.0);
  EXPECT_DOUBLE_EQ(*parse_duration("2h"), 7200.0);
  EXPECT_DOUBLE_EQ(*parse_duration("1h30m"), 5400.0);
  EXPECT_DOUBLE_EQ(*parse_duration("1.5h"), 5400.0);
  EXPECT_DOUBLE_EQ(*parse_duration("300"), 300.0);
  EXPECT_DOUBLE_EQ(*parse_duration("2m30s"), 150.0);
}

TEST(Duration, Refused) {
  for (const char* bad : {"", "m", "5x", "-5m", "5 m", "1h30", "abc", "5mm"})
    EXPECT_FALSE(parse_duration(bad).has_value()) << bad;
}
