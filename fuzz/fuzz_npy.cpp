// libFuzzer target: the .npy reader (data/npy, torch-free) on arbitrary bytes. parse_npy must
// either return or throw InputError; any other exception, a crash, a sanitizer report (an
// allocation over -rss_limit_mb included) or an array whose data does not hold exactly the
// product of its shape is a finding.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "data/npy.h"
#include "util/errors.h"

namespace {

[[noreturn]] void finding(const char* what) {
  std::fprintf(stderr, "fuzz_npy: %s\n", what);
  std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  try {
    const ablenerf::NpyArray a =
        ablenerf::parse_npy(std::string(reinterpret_cast<const char*>(data), size), "input.npy");
    // The product, zero as soon as one dimension is (the others may then be huge).
    bool zero = false;
    for (const int64_t d : a.shape) {
      if (d < 0) finding("negative dimension");
      zero = zero || d == 0;
    }
    uint64_t count = zero ? 0 : 1;
    for (const int64_t d : a.shape) {
      if (zero) break;
      if (count > a.data.size() / static_cast<uint64_t>(d)) finding("shape product exceeds the data");
      count *= static_cast<uint64_t>(d);
    }
    if (a.data.size() != count) finding("data size is not the product of the shape");
  } catch (const ablenerf::InputError&) {
    // Refused with a message: the expected outcome for bad bytes.
  }
  return 0;
}
