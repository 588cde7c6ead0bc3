// The demo scene as a phone capture (`synth --exposure-jitter / --white-balance-jitter /
// --pose-noise-deg / --pose-noise-shift`): the train photos carry exactly the gains and the poses
// scene.json records, checked against the clean dataset of the same seed (the gains in linear
// light, the rotation angle and the shift by their closed forms); the test views stay clean; a
// distractor ball sits exactly where the written masks leave out.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <nlohmann/json.hpp>
#include <string>

#include "synth/scene.h"
#include "test_util.h"
#include "util/errors.h"
#include "util/fs.h"
#include "util/image_io.h"

using namespace ablenerf;
using nlohmann::json;

namespace {

SynthOptions small(uint64_t seed) {
  SynthOptions o;
  o.res = 24;
  o.train_views = 6;
  o.test_views = 2;
  o.threads = 1;
  o.seed = seed;
  o.background = "environment";  // every pixel lit, so every pixel carries the gain
  o.layout = "blender";
  return o;
}

// IEC 61966-2-1's encoding of one linear value, written out.
double linear_to_srgb_for_test(double x) { return x <= 0.0031308 ? 12.92 * x : 1.055 * std::pow(x, 1 / 2.4) - 0.055; }

// IEC 61966-2-1's inverse, the decoder of what synth encodes.
torch::Tensor srgb_to_linear(const torch::Tensor& s) {
  return torch::where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055).pow(2.4));
}

// (3,3) rotation and centre of a 4x4 transform_matrix written as JSON.
torch::Tensor rotation_of(const json& m) {
  auto r = torch::zeros({3, 3}, torch::kDouble);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) r[i][j] = m[i][j].get<double>();
  return r;
}
torch::Tensor centre_of(const json& m) {
  return torch::tensor({m[0][3].get<double>(), m[1][3].get<double>(), m[2][3].get<double>()}, torch::kDouble);
}

}  // namespace

TEST(SynthJitter, TrainPhotosCarryTheRecordedGainsAndPoses) {
  test::TempDir clean_dir, jitter_dir;
  write_synthetic_dataset(clean_dir.path(), small(7));
  SynthOptions o = small(7);
  o.exposure_jitter = 1.0;
  o.white_balance_jitter = 0.5;
  o.pose_noise_deg = 2.0;
  o.pose_noise_shift = 0.03;
  write_synthetic_dataset(jitter_dir.path(), o);

  const json scene = json::parse(read_file(jitter_dir / "scene.json"));
  const json& truth = scene.at("train_view_truth");
  ASSERT_EQ(truth.size(), 6u);
  const json clean_frames = json::parse(read_file(clean_dir / "transforms_train.json")).at("frames");
  const json noisy_frames = json::parse(read_file(jitter_dir / "transforms_train.json")).at("frames");
  double exposure_sum = 0, red_sum = 0;
  bool some_gain_far_from_one = false;
  for (size_t k = 0; k < truth.size(); ++k) {
    const json& t = truth[k];
    exposure_sum += t.at("exposure_stops").get<double>();
    red_sum += t.at("red_stops").get<double>();
    EXPECT_LE(std::abs(t.at("exposure_stops").get<double>()), 2.0);  // within 2 s after centring
    // The gains: exposure on every channel, white balance on red and blue.
    const double g = std::exp2(t.at("exposure_stops").get<double>());
    const auto gain = t.at("gain_rgb");
    EXPECT_NEAR(gain[0].get<double>(), g * std::exp2(t.at("red_stops").get<double>()), 1e-12);
    EXPECT_NEAR(gain[1].get<double>(), g, 1e-12);
    EXPECT_NEAR(gain[2].get<double>(), g * std::exp2(t.at("blue_stops").get<double>()), 1e-12);

    // In linear light each channel of the photo is the clean photo's times its gain, where neither
    // is near the film's limits: the median ratio over those pixels, within 8-bit rounding.
    const std::string name = "/train/r_" + std::to_string(k) + ".png";
    const auto a = srgb_to_linear(read_png(clean_dir.path() + name).to(torch::kDouble).slice(2, 0, 3) / 255.0);
    const auto b = srgb_to_linear(read_png(jitter_dir.path() + name).to(torch::kDouble).slice(2, 0, 3) / 255.0);
    for (int c = 0; c < 3; ++c) {
      const auto ac = a.select(2, c).flatten(), bc = b.select(2, c).flatten();
      const auto ok = (ac > 0.02) & (ac < 0.8) & (bc > 0.02) & (bc < 0.8);
      ASSERT_GT(ok.sum().item<int64_t>(), 20) << "view " << k << " channel " << c;
      const double ratio = (bc.masked_select(ok) / ac.masked_select(ok)).median().item<double>();
      EXPECT_NEAR(ratio, gain[c].get<double>(), 0.02 * gain[c].get<double>()) << "view " << k << " channel " << c;
      if (std::abs(gain[c].get<double>() - 1) > 0.2) some_gain_far_from_one = true;
    }

    // The true pose is the clean dataset's; the written one is turned by exactly 2 degrees and its
    // centre moved by 3% of the camera's distance.
    const json& true_m = t.at("true_transform_matrix");
    const json& clean_m = clean_frames[k].at("transform_matrix");
    const json& noisy_m = noisy_frames[k].at("transform_matrix");
    EXPECT_TRUE(torch::allclose(rotation_of(true_m), rotation_of(clean_m), 0, 1e-12));
    EXPECT_TRUE(torch::allclose(centre_of(true_m), centre_of(clean_m), 0, 1e-12));
    const auto rel = torch::matmul(rotation_of(noisy_m).t(), rotation_of(true_m));
    const double angle = std::acos(std::clamp((rel.trace().item<double>() - 1) / 2, -1.0, 1.0)) * 180 / M_PI;
    EXPECT_NEAR(angle, 2.0, 1e-6) << "view " << k;
    const double dist = centre_of(true_m).norm().item<double>();
    EXPECT_NEAR((centre_of(noisy_m) - centre_of(true_m)).norm().item<double>(), 0.03 * dist, 1e-9);
  }
  EXPECT_NEAR(exposure_sum, 0.0, 1e-12);  // centred: the clean look is the views' average
  EXPECT_NEAR(red_sum, 0.0, 1e-12);
  EXPECT_TRUE(some_gain_far_from_one);
  // The test views are the clean ones, byte for byte.
  for (const std::string f : {"/test/r_0.png", "/test/r_1.png", "/transforms_test.json"})
    EXPECT_EQ(read_file(clean_dir.path() + f), read_file(jitter_dir.path() + f)) << f;
}

TEST(SynthJitter, OutOfRangeOptionsNameTheFlag) {
  SynthOptions o = small(1);
  o.exposure_jitter = 5;
  test::expect_input_error([&] { synth::validate(o); }, "synth", "--exposure-jitter", "between 0 and 4 stops", true);
  o = small(1);
  o.white_balance_jitter = -1;
  test::expect_input_error([&] { synth::validate(o); }, "synth", "--white-balance-jitter", "stops", true);
  o = small(1);
  o.pose_noise_deg = 90;
  test::expect_input_error([&] { synth::validate(o); }, "synth", "--pose-noise-deg", "45 degrees", true);
  o = small(1);
  o.pose_noise_shift = 0.6;
  test::expect_input_error([&] { synth::validate(o); }, "synth", "--pose-noise-shift", "0.5", true);
}

// A distractor (`synth --distractor`): every train photo differs from the clean one exactly where
// its mask is black, and there the photo is the ball's magenta; the ball's pixels move from photo to
// photo; frames name their masks; the ball sits between its camera and the objects; the test views
// are the clean ones.
TEST(SynthJitter, TheDistractorIsWhereTheMaskLeavesOut) {
  test::TempDir clean_dir, ball_dir;
  write_synthetic_dataset(clean_dir.path(), small(9));
  SynthOptions o = small(9);
  o.distractor = true;
  write_synthetic_dataset(ball_dir.path(), o);
  const json frames = json::parse(read_file(ball_dir / "transforms_train.json")).at("frames");
  const json balls = json::parse(read_file(ball_dir / "scene.json")).at("train_distractors").at("balls");
  ASSERT_EQ(balls.size(), 6u);
  const double magenta[3] = {linear_to_srgb_for_test(0.9), linear_to_srgb_for_test(0.02), linear_to_srgb_for_test(0.7)};
  torch::Tensor previous;
  for (size_t k = 0; k < 6; ++k) {
    const std::string stem = "/train/r_" + std::to_string(k);
    EXPECT_EQ(frames[k].at("mask_path").get<std::string>(), "." + stem + "_mask.png");
    const auto mask = read_png(ball_dir.path() + stem + "_mask.png").to(torch::kDouble).select(2, 0) / 255.0;
    const auto a = read_png(clean_dir.path() + stem + ".png").to(torch::kDouble).slice(2, 0, 3) / 255.0;
    const auto b = read_png(ball_dir.path() + stem + ".png").to(torch::kDouble).slice(2, 0, 3) / 255.0;
    const auto left_out = mask < 0.5;
    const int64_t n = left_out.sum().item<int64_t>();
    EXPECT_GT(n, 3) << "view " << k;            // the ball is in the picture
    EXPECT_LT(n, 24 * 24 / 2) << "view " << k;  // and small
    // Outside the mask the photo is the clean one, byte for byte.
    EXPECT_EQ((a - b).abs().sum(-1).masked_select(~left_out).max().item<double>(), 0.0) << "view " << k;
    // Where every sub-sample saw the ball (the pixel differs most from the clean one), it is magenta.
    for (int c = 0; c < 3; ++c)
      EXPECT_NEAR(b.select(2, c).masked_select(left_out).median().item<double>(), magenta[c], 0.25) << k << c;
    if (previous.defined()) EXPECT_FALSE(torch::equal(left_out, previous)) << "view " << k;
    previous = left_out;
    // Between its camera and the objects (which lie within 1.3 of the origin).
    const json& c = balls[k].at("centre");
    const double r =
        std::sqrt(std::pow(c[0].get<double>(), 2) + std::pow(c[1].get<double>(), 2) + std::pow(c[2].get<double>(), 2));
    EXPECT_GT(r, 1.3 + 0.25);
  }
  for (const std::string f : {"/test/r_0.png", "/test/r_1.png", "/transforms_test.json"})
    EXPECT_EQ(read_file(clean_dir.path() + f), read_file(ball_dir.path() + f)) << f;
}
