#pragma once
// NumPy .npy files (format versions 1-3) holding float32 or float64 arrays, little- or big-endian,
// C or Fortran order, read without LibTorch (fuzzed): LLFF's poses_bounds.npy. Refusals are
// InputErrors naming the file and the header field.
#include <cstdint>
#include <string>
#include <vector>

namespace ablenerf {

struct NpyArray {
  std::vector<int64_t> shape;
  std::vector<double> data;  // C order
};

NpyArray parse_npy(const std::string& bytes, const std::string& origin);
NpyArray read_npy(const std::string& path);

}  // namespace ablenerf
