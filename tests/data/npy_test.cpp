// NumPy .npy reader (data/npy): files assembled byte by byte here (magic, version, header dict,
// raw values) for float64 and float32, little- and big-endian, C and Fortran order, format
// versions 1.0 and 2.0, 0-d and 1-d shapes and headers written in unusual but valid ways; then
// the refusals. Torch-free.
#include "data/npy.h"
#include "test_util.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "util/errors.h"

using namespace ablenerf;
namespace fs = std::filesystem;

using test::npy_file;

namespace {

// Little- or big-endian bytes of each value, as float64 or float32.
std::string raw_values(const std::vector<double>& v, bool f32, bool big_endian = false) {
  std::string out;
  for (const double d : v) {
    uint64_t bits = 0;
    size_t n = 8;
    if (f32) {
      const float f = static_cast<float>(d);
      uint32_t u;
      std::memcpy(&u, &f, 4);
      bits = u;
      n = 4;
    } else {
      std::memcpy(&bits, &d, 8);
    }
    for (size_t k = 0; k < n; ++k) {
      const size_t shift = 8 * (big_endian ? n - 1 - k : k);
      out += static_cast<char>((bits >> shift) & 0xff);
    }
  }
  return out;
}

void expect_npy_refused(const std::function<void()>& f, const std::string& field, const std::string& what) {
  test::expect_input_error(f, "x.npy", field, what, /*exact_field=*/true);
}

const std::vector<double> kSix = {1.5, -2.25, 3e10, 0.1, -0.0, 6};

}  // namespace

TEST(Npy, Float64COrder) {
  const NpyArray a = parse_npy(
      npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }", raw_values(kSix, false)), "x.npy");
  EXPECT_EQ(a.shape, (std::vector<int64_t>{2, 3}));
  EXPECT_EQ(a.data, kSix);  // bit for bit
  EXPECT_TRUE(std::signbit(a.data[4]));
}

TEST(Npy, FortranOrderTransposesIntoCOrder) {
  // A 2x3 matrix m[i][j] = 10 i + j, stored column by column: m00 m10 m01 m11 m02 m12.
  const std::vector<double> columns = {0, 10, 1, 11, 2, 12};
  const NpyArray a = parse_npy(
      npy_file("{'descr': '<f8', 'fortran_order': True, 'shape': (2, 3), }", raw_values(columns, false)), "x.npy");
  ASSERT_EQ(a.shape, (std::vector<int64_t>{2, 3}));
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j) EXPECT_EQ(a.data[static_cast<size_t>(i * 3 + j)], 10 * i + j) << i << "," << j;
  // 3-d: t[i][j][k] = 100 i + 10 j + k with shape (2, 3, 4), first index fastest in the file.
  std::vector<double> f;
  for (int k = 0; k < 4; ++k)
    for (int j = 0; j < 3; ++j)
      for (int i = 0; i < 2; ++i) f.push_back(100 * i + 10 * j + k);
  const NpyArray t = parse_npy(
      npy_file("{'descr': '<f4', 'fortran_order': True, 'shape': (2, 3, 4), }", raw_values(f, true)), "x.npy");
  ASSERT_EQ(t.data.size(), 24u);
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 4; ++k)
        EXPECT_EQ(t.data[static_cast<size_t>((i * 3 + j) * 4 + k)], 100 * i + 10 * j + k) << i << j << k;
}

TEST(Npy, Float32AndBigEndian) {
  const NpyArray f =
      parse_npy(npy_file("{'descr': '<f4', 'fortran_order': False, 'shape': (6,), }", raw_values(kSix, true)), "x.npy");
  ASSERT_EQ(f.shape, (std::vector<int64_t>{6}));
  for (size_t k = 0; k < kSix.size(); ++k) EXPECT_EQ(f.data[k], static_cast<double>(static_cast<float>(kSix[k])));
  EXPECT_EQ(f.data[3], static_cast<double>(0.1f));  // float32's 0.1, widened exactly
  const NpyArray b = parse_npy(
      npy_file("{'descr': '>f8', 'fortran_order': False, 'shape': (3, 2), }", raw_values(kSix, false, true)), "x.npy");
  EXPECT_EQ(b.data, kSix);
  const NpyArray b4 = parse_npy(
      npy_file("{'descr': '>f4', 'fortran_order': False, 'shape': (6,), }", raw_values(kSix, true, true)), "x.npy");
  EXPECT_EQ(b4.data, f.data);
}

TEST(Npy, VersionsShapesAndHeaderSpellings) {
  // Version 2.0 (uint32 header length) and 3.0.
  for (int major : {2, 3}) {
    const NpyArray a = parse_npy(
        npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (6,), }", raw_values(kSix, false), major), "x.npy");
    EXPECT_EQ(a.data, kSix) << "version " << major;
  }
  // A 0-d array: one value, no dimensions.
  const NpyArray s =
      parse_npy(npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (), }", raw_values({4.5}, false)), "x.npy");
  EXPECT_TRUE(s.shape.empty());
  EXPECT_EQ(s.data, (std::vector<double>{4.5}));
  // Keys in another order, double quotes, no trailing comma, odd spacing, Python 2's 6L.
  const NpyArray o = parse_npy(
      npy_file("{ \"shape\" :(6L ,) ,\"fortran_order\":False,\"descr\":\"<f8\"}", raw_values(kSix, false)), "x.npy");
  EXPECT_EQ(o.shape, (std::vector<int64_t>{6}));
  EXPECT_EQ(o.data, kSix);
  // An empty array.
  const NpyArray e = parse_npy(npy_file("{'descr': '<f8', 'fortran_order': True, 'shape': (0, 17), }", ""), "x.npy");
  EXPECT_EQ(e.shape, (std::vector<int64_t>{0, 17}));
  EXPECT_TRUE(e.data.empty());
  // Non-finite values are read; the caller decides.
  const NpyArray n = parse_npy(
      npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (1,), }", raw_values({NAN}, false)), "x.npy");
  EXPECT_TRUE(std::isnan(n.data[0]));
}

TEST(Npy, ReadsFromDisk) {
  const std::string path =
      (fs::temp_directory_path() / ("ablenerf_npy_test_" + std::to_string(::getpid()) + ".npy")).string();
  {
    std::ofstream f(path, std::ios::binary);
    f << npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }", raw_values(kSix, false));
  }
  const NpyArray a = read_npy(path);
  EXPECT_EQ(a.data, kSix);
  fs::remove(path);
  try {
    read_npy(path);
    ADD_FAILURE() << "a missing file must be refused";
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), path);
  }
}

TEST(Npy, Refusals) {
  const std::string six = raw_values(kSix, false);
  const std::string good = npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3), }", six);
  const auto parse = [](const std::string& b) { return [b] { parse_npy(b, "x.npy"); }; };

  std::string bad_magic = good;
  bad_magic[1] = 'M';
  expect_npy_refused(parse(bad_magic), "header", "not a .npy file");
  expect_npy_refused(parse("\x93NUM"), "header", "not a .npy file");
  std::string v4 = good;
  v4[6] = 4;
  expect_npy_refused(parse(v4), "header", "unsupported .npy format version 4.0");
  std::string minor = good;
  minor[7] = 1;
  expect_npy_refused(parse(minor), "header", "version 1.1");
  // Header length past the end of the file (and a file cut inside the length itself).
  std::string long_header = good;
  long_header[8] = '\xff';
  long_header[9] = '\x7f';
  expect_npy_refused(parse(long_header), "header", "runs past the end");
  expect_npy_refused(parse(good.substr(0, 9)), "header", "truncated");
  expect_npy_refused(parse(good.substr(0, 40)), "header", "runs past the end");

  expect_npy_refused(parse(npy_file("{'descr': '<i8', 'fortran_order': False, 'shape': (2, 3), }", six)), "descr",
                     "dtype '<i8' not supported (need float32 or float64)");
  expect_npy_refused(parse(npy_file("{'descr': [('a', '<f8')], 'fortran_order': False, 'shape': (6,), }", six)),
                     "descr", "structured");
  expect_npy_refused(parse(npy_file("{'fortran_order': False, 'shape': (2, 3), }", six)), "header", "no 'descr'");
  expect_npy_refused(parse(npy_file("{'descr': '<f8', 'shape': (2, 3), }", six)), "header", "no 'fortran_order'");
  expect_npy_refused(parse(npy_file("{'descr': '<f8', 'fortran_order': False, }", six)), "header", "no 'shape'");
  expect_npy_refused(parse(npy_file("{'descr': '<f8', 'fortran_order': 0, 'shape': (2, 3), }", six)), "fortran_order",
                     "True or False");
  expect_npy_refused(parse(npy_file("['descr', '<f8']", six)), "header", "not a dict");
  expect_npy_refused(parse(npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (2, 3)} x", six)), "header",
                     "after the dict");

  // Shape against data: one value short, one value too many, and products that overflow.
  expect_npy_refused(parse(npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (7,), }", six)), "data",
                     "expected 56 bytes, file has 48");
  expect_npy_refused(parse(npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (5,), }", six)), "data",
                     "expected 40 bytes, file has 48");
  expect_npy_refused(parse(npy_file("{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }", six)), "data",
                     "expected 24 bytes, file has 48");
  expect_npy_refused(
      parse(npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (4294967296, 4294967296), }", six)), "shape",
      "overflows");
  expect_npy_refused(
      parse(npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (99999999999999999999,), }", six)), "shape",
      "too large");
  expect_npy_refused(parse(npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': (-6,), }", six)), "shape",
                     "whole numbers");
  expect_npy_refused(parse(npy_file("{'descr': '<f8', 'fortran_order': False, 'shape': [6], }", six)), "shape",
                     "tuple");
}
