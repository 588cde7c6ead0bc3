// PLY point reader (data/ply): ASCII and binary little-endian files written here byte by byte
// read back to the values written, every scalar type, other elements after the vertices, and the
// refusals (not PLY, big-endian, list or missing coordinates, truncation, huge counts, non-finite).
#include "data/ply.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>
#include <string>

#include "test_util.h"
#include "util/errors.h"

using namespace ablenerf;

namespace {

template <class T>
std::string le(T v) {
  std::string s(sizeof(T), '\0');
  std::memcpy(s.data(), &v, sizeof(T));  // the test machines are little-endian (x86-64)
  return s;
}

const std::string kAsciiHeader =
    "ply\nformat ascii 1.0\ncomment made by a test\nelement vertex 3\nproperty float x\nproperty float y\n"
    "property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n";

void expect_refused(const std::string& bytes, const std::string& field, const std::string& what) {
  test::expect_input_error([&] { parse_ply_points(bytes, "cloud.ply"); }, "cloud.ply", field, what, true);
}

}  // namespace

TEST(Ply, AsciiReadsTheCoordinates) {
  const auto p =
      parse_ply_points(kAsciiHeader + "0.5 1 -2 255 0 0\n1e-3 -4 7 1 2 3\r\n-0.25 0 8.5 9 9 9\n", "cloud.ply");
  ASSERT_EQ(p.size(), 3u);
  EXPECT_DOUBLE_EQ(p[0][0], 0.5);
  EXPECT_DOUBLE_EQ(p[0][2], -2);
  EXPECT_DOUBLE_EQ(p[1][0], 1e-3);
  EXPECT_DOUBLE_EQ(p[2][2], 8.5);
}

TEST(Ply, BinaryEveryScalarTypeAndTrailingElements) {
  // x double, colour bytes between, y as int16, z as float, then a short, an unsigned int; a face
  // element after the vertices (not read).
  const std::string header =
      "ply\r\nformat binary_little_endian 1.0\r\nelement vertex 2\r\nproperty double x\r\nproperty uint8 red\r\n"
      "property short y\r\nproperty float32 z\r\nproperty char a\r\nproperty uint b\r\nelement face 1\r\n"
      "property list uchar int vertex_indices\r\nend_header\r\n";
  std::string body;
  body += le<double>(1.25) + le<uint8_t>(200) + le<int16_t>(-300) + le<float>(0.5f) + le<int8_t>(-1) + le<uint32_t>(7);
  body += le<double>(-4) + le<uint8_t>(1) + le<int16_t>(12) + le<float>(-2.25f) + le<int8_t>(5) + le<uint32_t>(9);
  body += std::string("\x03\0\0\0\0\x01\0\0\0\x02\0\0\0", 13);
  const auto p = parse_ply_points(header + body, "cloud.ply");
  ASSERT_EQ(p.size(), 2u);
  EXPECT_EQ(p[0], (std::array<double, 3>{1.25, -300, 0.5}));
  EXPECT_EQ(p[1], (std::array<double, 3>{-4, 12, -2.25}));
  // Cut inside the second vertex: refused, naming the data.
  expect_refused(header + body.substr(0, 20), "data", "truncated");
}

TEST(Ply, Refusals) {
  expect_refused("PLY\nformat ascii 1.0\nend_header\n", "header", "not a PLY");
  expect_refused("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n", "header", "end_header");
  expect_refused("ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty float x\nend_header\n", "header",
                 "big_endian");
  expect_refused("ply\nformat ascii 1.0\nelement face 1\nproperty list uchar int i\nend_header\n", "vertex",
                 "first element");
  expect_refused("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
                 "vertex", "x, y and z");
  expect_refused("ply\nformat ascii 1.0\nelement vertex 1\nproperty list uchar float x\nend_header\n", "vertex",
                 "list");
  expect_refused("ply\nformat ascii 1.0\nelement vertex 1\nproperty half x\nend_header\n", "vertex", "bad property");
  expect_refused("ply\nformat ascii 1.0\nelement vertex 99999999999\nproperty float x\nend_header\n", "vertex",
                 "count");
  expect_refused(
      "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
      "data", "truncated");
  expect_refused(kAsciiHeader + "1 2 3 0 0 0\n4 5\n", "data", "expected 6 numbers");
  expect_refused("ply\nformat ascii 1.0\nbogus line\nend_header\n", "header", "unknown header line");
  // A binary file claiming more vertices than it holds fails before allocating them.
  expect_refused(
      "ply\nformat binary_little_endian 1.0\nelement vertex 40000000\nproperty double x\nproperty double y\n"
      "property double z\nend_header\n" +
          le<double>(1) + le<double>(2) + le<double>(3),
      "data", "truncated");
  const double inf = std::numeric_limits<double>::infinity();
  expect_refused(
      "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty double x\nproperty double y\n"
      "property double z\nend_header\n" +
          le<double>(1) + le<double>(inf) + le<double>(3),
      "data", "not finite");
}
