// LPIPS (AlexNet v0.1) with the weights shipped in assets/ (fp16 copy) against the reference
// distances computed with the LPIPS authors' code for the example pairs in assets/lpips_examples/
// (assets/LPIPS_WEIGHTS.md), the default weights lookup, and the loader's input errors.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "eval/lpips.h"
#include "eval/metrics.h"
#include "test_util.h"
#include "util/errors.h"

namespace ablenerf {
namespace {

// Tolerance of the brief; the README's references are rounded to 4 decimals.
constexpr double kRefTolerance = 1e-3;

// The copy shipped with the repository (float16 tensors; the loader converts them to float32).
std::string weights_file() { return test::source_dir() + "/assets/lpips_alex_v0.1.pt"; }

torch::Tensor example(const std::string& name) {
  return read_rgb_for_metrics(test::source_dir() + "/assets/lpips_examples/" + name + ".png");
}

void save_dict(const std::string& path, const c10::Dict<std::string, torch::Tensor>& dict) {
  const std::vector<char> bytes = torch::pickle_save(c10::IValue(dict));
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// The field of the InputError raised when loading `path` ("" if none is raised).
std::string error_field(const std::string& path) {
  try {
    Lpips l(path);
  } catch (const InputError& e) {
    EXPECT_EQ(e.file(), path);
    return e.field().empty() ? "<file>" : e.field();
  }
  return "";
}

TEST(Lpips, MatchesPublishedReferenceDistances) {
  Lpips lp(weights_file());
  const auto ref = example("ex_ref"), p0 = example("ex_p0"), p1 = example("ex_p1");
  ASSERT_EQ(ref.sizes(), (std::vector<int64_t>{64, 64, 3}));
  EXPECT_NEAR(lp.distance(p0, ref), 0.7796, kRefTolerance);
  EXPECT_NEAR(lp.distance(p1, ref), 0.0913, kRefTolerance);
  EXPECT_NEAR(lp.distance(ref, ref), 0.0, 1e-7);
}

TEST(Lpips, BatchedEqualsSingleAndIsSymmetric) {
  Lpips lp(weights_file());
  const auto ref = example("ex_ref"), p0 = example("ex_p0"), p1 = example("ex_p1");
  auto d = lp.distances(torch::stack({p0, p1}), torch::stack({ref, ref}));
  ASSERT_EQ(d.sizes(), (std::vector<int64_t>{2}));
  EXPECT_NEAR(d[0].item<double>(), lp.distance(p0, ref), 1e-5);
  EXPECT_NEAR(d[1].item<double>(), lp.distance(p1, ref), 1e-5);
  EXPECT_NEAR(lp.distance(ref, p0), lp.distance(p0, ref), 1e-5);
}

TEST(Lpips, RejectsImagesBelowAlexNetMinimum) {
  Lpips lp(weights_file());
  const int64_t s = Lpips::kMinSide;
  EXPECT_NO_THROW(lp.distance(torch::rand({s, s, 3}), torch::rand({s, s, 3})));
  EXPECT_THROW(lp.distance(torch::rand({s - 1, s, 3}), torch::rand({s - 1, s, 3})), c10::Error);
}

TEST(Lpips, MissingFileIsAnInputError) {
  test::TempDir dir("lpips");
  EXPECT_EQ(error_field(dir / "absent.pt"), "<file>");
}

TEST(Lpips, NonTorchFileIsAnInputError) {
  test::TempDir dir("lpips");
  test::write_file(dir / "junk.pt", "not a zip archive");
  EXPECT_EQ(error_field(dir / "junk.pt"), "<file>");
}

TEST(Lpips, MissingKeyIsNamed) {
  test::TempDir dir("lpips");
  c10::Dict<std::string, torch::Tensor> dict;
  dict.insert("features.0.weight", torch::zeros({64, 3, 11, 11}));
  save_dict(dir / "partial.pt", dict);
  EXPECT_EQ(error_field(dir / "partial.pt"), "features.0.bias");
}

TEST(Lpips, WrongShapeIsNamed) {
  test::TempDir dir("lpips");
  c10::Dict<std::string, torch::Tensor> dict;
  dict.insert("features.0.weight", torch::zeros({64, 3, 5, 5}));
  save_dict(dir / "shape.pt", dict);
  EXPECT_EQ(error_field(dir / "shape.pt"), "features.0.weight");
}

// The shipped weights are stored in float16: they must be the float32 originals rounded to
// float16 (checked against the shared folder's original where it is present) and load as float32.
TEST(Lpips, ShippedWeightsAreTheOriginalRoundedToHalf) {
  const std::string shared = test::shared_weights_dir();
  if (shared.empty()) GTEST_SKIP() << "no shared fp32 original (the reference distances still check the asset)";
  auto read_dict = [](const std::string& path) {
    std::ifstream in(path, std::ios::binary);
    std::vector<char> bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    return torch::pickle_load(bytes).toGenericDict();
  };
  const auto half = read_dict(weights_file());
  const auto full = read_dict(shared + "/lpips_alex_v0.1.pt");
  ASSERT_EQ(half.size(), full.size());
  for (const auto& kv : full) {
    const std::string key = kv.key().toStringRef();
    ASSERT_TRUE(half.contains(kv.key())) << key;
    const torch::Tensor h = half.at(kv.key()).toTensor(), f = kv.value().toTensor();
    EXPECT_EQ(h.scalar_type(), torch::kHalf) << key;
    EXPECT_TRUE(torch::equal(h, f.to(torch::kHalf))) << key;
  }
}

TEST(Lpips, DefaultPathHonoursEnvironmentThenFindsTheShippedCopy) {
  const char* old = std::getenv("ABLENERF_LPIPS_WEIGHTS");
  const std::string saved = old ? old : "";
  ::setenv("ABLENERF_LPIPS_WEIGHTS", "/some/where/w.pt", 1);
  EXPECT_EQ(default_lpips_weights_path(), "/some/where/w.pt");
  ::unsetenv("ABLENERF_LPIPS_WEIGHTS");
  // An installed tree's share/ablenerf/assets/ comes first (absent beside a build folder), the
  // source tree's assets/ after it, present in every checkout: a test binary finds that copy.
  const auto candidates = lpips_weights_candidates();
  ASSERT_GE(candidates.size(), 3u);
  EXPECT_NE(candidates.front().find("share/ablenerf/assets/lpips_alex_v0.1.pt"), std::string::npos)
      << candidates.front();
  const auto shipped = std::filesystem::path(ABLENERF_SOURCE_DIR) / "assets" / "lpips_alex_v0.1.pt";
  EXPECT_NE(std::find(candidates.begin(), candidates.end(), shipped.string()), candidates.end());
  EXPECT_TRUE(std::filesystem::equivalent(default_lpips_weights_path(), shipped));
  if (old) ::setenv("ABLENERF_LPIPS_WEIGHTS", saved.c_str(), 1);
}

}  // namespace
}  // namespace ablenerf
