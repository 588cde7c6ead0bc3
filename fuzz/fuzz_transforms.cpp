// libFuzzer target: the dataset loader (Blender transforms_train.json or a single
// transforms.json, chosen by the first byte) on arbitrary json text, beside one valid 2x2 PNG
// (r_0.png) so that well-formed inputs reach pose parsing, path resolution and decoding.
// Dataset::load must either load or throw InputError; anything else is a finding.
#include <cstdint>
#include <filesystem>

#include "data/dataset.h"
#include "fuzz_common.h"
#include "util/errors.h"
#include "util/image_io.h"

namespace {

constexpr int kImageSide = 2;
// Refuse to decode more than this, so that a json listing thousands of frames measures the
// loader, not the allocator (check_memory must refuse it up front).
constexpr int64_t kMemoryLimitBytes = int64_t(64) << 20;

std::string dataset_dir() {
  static const std::string dir = [] {
    const std::string d = ablenerf::fuzz::scratch_dir() + "/data";
    std::filesystem::create_directories(d);
    ablenerf::write_png(d + "/r_0.png", torch::full({kImageSide, kImageSide, 4}, 0.5f));
    return d;
  }();
  return dir;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size == 0) return 0;
  const std::string dir = dataset_dir();
  // Low bit of the first byte: Blender layout or instant-ngp layout. Only one json exists at a time.
  const bool blender = (data[0] & 1) == 0;
  const std::string keep = dir + (blender ? "/transforms_train.json" : "/transforms.json");
  const std::string drop = dir + (blender ? "/transforms.json" : "/transforms_train.json");
  std::error_code ec;
  std::filesystem::remove(drop, ec);
  ablenerf::fuzz::write_bytes(keep, data + 1, size - 1);
  ablenerf::LoadOptions opts;
  opts.memory_limit_bytes = kMemoryLimitBytes;
  try {
    const ablenerf::Dataset ds = ablenerf::Dataset::load(dir, opts);
    (void)ds;
  } catch (const ablenerf::InputError&) {
    // Refused with a message naming the file and field: expected for bad input.
  }
  return 0;
}
