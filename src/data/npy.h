#pragma once
// NumPy .npy files (format versions 1.0, 2.0 and 3.0) holding a float32 or float64 array, little-
// or big-endian, C or Fortran order, any number of dimensions: LLFF's poses_bounds.npy. Read
// without LibTorch and fuzzed (fuzz/fuzz_npy.cpp): the header dict is parsed by a small tolerant
// reader of the literal numpy writes (keys in any order, either quote, trailing commas), not by a
// Python parser. Refusals are InputErrors naming the file and "header", "descr", "fortran_order",
// "shape" or "data". Non-finite values are read as they are: the caller decides.
#include <cstdint>
#include <string>
#include <vector>

namespace ablenerf {

struct NpyArray {
  std::vector<int64_t> shape;  // empty for a 0-d (scalar) array
  std::vector<double> data;    // C order; exactly the product of `shape` values (1 for a scalar)
};

// Parses a whole .npy file held in memory; `origin` names it in errors.
NpyArray parse_npy(const std::string& bytes, const std::string& origin);
// Reads and parses the .npy file at `path`.
NpyArray read_npy(const std::string& path);

}  // namespace ablenerf
