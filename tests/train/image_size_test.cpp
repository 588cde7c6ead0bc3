// The image size chosen from the capture (train/image_size.h, data.downscale = 0): by hand on
// captures of known sizes, against the rule's two conditions (the finest candidate whose pixels
// the run draws auto_passes times, never below auto_min_side on the short side).
#include <gtest/gtest.h>

#include "data/data_config.h"
#include "train/image_size.h"
#include "train/train_config.h"
#include "util/config.h"

namespace ablenerf {
namespace {

Capture capture_of(int width, int height, int train_frames) {
  Capture c;
  c.width = width, c.height = height;
  c.splits.push_back({"train", "", std::vector<CaptureFrame>(static_cast<size_t>(train_frames))});
  c.splits.push_back({"test", "", std::vector<CaptureFrame>(3)});  // held-out photos never count
  return c;
}

Config config_of(double budget_s, int64_t steps, int64_t rays_per_step) {
  Config cfg;
  cfg.get<TrainConfig>().time_budget_s = budget_s;
  cfg.get<TrainConfig>().steps = steps;
  cfg.get<TrainConfig>().rays_per_step = rays_per_step;
  cfg.get<DataConfig>().downscale = 0;
  cfg.get<DataConfig>().auto_passes = 4;
  cfg.get<DataConfig>().auto_min_side = 64;
  return cfg;
}

TEST(ImageSize, PlannedRaysAreTheStepsOrTheBudgetWhicheverEndsFirst) {
  EXPECT_DOUBLE_EQ(planned_rays(config_of(0, 100, 256), 7500), 25600);         // no budget: the steps
  EXPECT_DOUBLE_EQ(planned_rays(config_of(900, 1000000, 256), 7500), 6.75e6);  // the budget first
  EXPECT_DOUBLE_EQ(planned_rays(config_of(900, 10, 256), 7500), 2560);         // the steps first
}

// 45 phone frames of 1920x1080 in 15 minutes at 7,500 rays/s (6.75M rays, 4 passes: at most 1.69M
// pixels): 1/6 is 320x180 x 45 = 2.59M pixels, too many; 1/8 is 240x135 x 45 = 1.46M.
TEST(ImageSize, PhoneFramesInFifteenMinutes) {
  const ImageSizeChoice c = choose_image_size(capture_of(1920, 1080, 45), config_of(900, 1000000, 256), 7500);
  EXPECT_EQ(c.downscale, 8);
  EXPECT_EQ(c.width, 240);
  EXPECT_EQ(c.height, 135);
  EXPECT_EQ(c.frames, 45);
  EXPECT_DOUBLE_EQ(c.pixels, 45.0 * 240 * 135);
  EXPECT_NEAR(c.passes(), 6.75e6 / (45.0 * 240 * 135), 1e-9);
  EXPECT_NE(c.describe().find("data.downscale = 8"), std::string::npos) << c.describe();
  // Twice the budget: 1/6 (2.59M pixels x 4 <= 13.5M rays).
  EXPECT_EQ(choose_image_size(capture_of(1920, 1080, 45), config_of(1800, 1000000, 256), 7500).downscale, 6);
}

// 4000x4000 photos, 58 of them: 1/16 (250x250, 3.6M pixels) is drawn 1.9 times, 1/24 (166x166,
// 1.6M) 4.2 times.
TEST(ImageSize, LargePhotosGoFurther) {
  EXPECT_EQ(choose_image_size(capture_of(4000, 4000, 58), config_of(900, 1000000, 256), 7500).downscale, 24);
}

// A run too short for any size: the coarsest that keeps 64 pixels on the short side (1080 / 16 =
// 67; 1080 / 24 = 45 would be below); photos already small stay at their size.
TEST(ImageSize, NeverBelowTheSmallestSide) {
  const ImageSizeChoice c = choose_image_size(capture_of(1920, 1080, 45), config_of(0, 10, 256), 0);
  EXPECT_EQ(c.downscale, 16);
  EXPECT_LT(c.passes(), 4);
  EXPECT_EQ(choose_image_size(capture_of(100, 80, 20), config_of(0, 1, 1), 0).downscale, 1);
  // And a run long enough for every pixel: full size.
  EXPECT_EQ(choose_image_size(capture_of(100, 80, 20), config_of(0, 1000, 1000), 0).downscale, 1);
}

// A capture that ships only images_8/ (LLFF's horns: 4032x3024 in its npy, 504x378 on disk) is
// read at 1/8 whatever the budget asks; one with full-size photos and images_8/ skips nothing.
TEST(ImageSize, OnlyReductionsTheCaptureCanBeReadAt) {
  const auto only_8 = [](int d) { return d == 8; };
  EXPECT_EQ(choose_image_size(capture_of(4032, 3024, 54), config_of(900, 1000000, 256), 7500, only_8).downscale, 8);
  EXPECT_EQ(choose_image_size(capture_of(4032, 3024, 54), config_of(0, 10, 256), 0, only_8).downscale, 8);
  // 54 photos of 4032x3024: 1/16 is 252x189 x 54 = 2.57M pixels, too many for 6.75M rays; 1/24 fits.
  EXPECT_EQ(choose_image_size(capture_of(4032, 3024, 54), config_of(900, 1000000, 256), 7500).downscale, 24);
}

}  // namespace
}  // namespace ablenerf
