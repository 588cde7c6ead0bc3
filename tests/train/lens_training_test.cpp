// Training through a distorted lens must match training on the undistorted images: the demo scene
// rendered through the synth's wide-angle lens and through a pinhole, same cameras, same seed, same
// short schedule. Both models are scored on the same pinhole test views (the distorted images show
// other pixels, so their own scores would not compare): the scene learnt through the lens must match
// the one learnt without it, and beat the same distorted images trained as if they were pinhole ones.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include "eval/evaluate.h"
#include "run/run_folder.h"
#include "train_fixture.h"
#include "util/fs.h"

#include <filesystem>
#include <nlohmann/json.hpp>

using namespace ablenerf;

namespace {

// Trains on `data`, then scores the run on the test views of `eval_data`.
double trained_psnr(const std::string& data, const std::string& run, const std::string& eval_data) {
  const Config c =
      test::config_with(test::tiny_config(), {"model.width=32", "model.samples=12", "model.le_count=4",
                                              "train.steps=300", "train.rays_per_step=128", "train.micro_batch=128",
                                              "train.lr_init=5e-3", "train.lr_final=5e-4", "train.lr_warmup_steps=20",
                                              "train.ckpt_every=0", "data.scene=bounded"});
  EXPECT_EQ(train(c, test::quiet_run(run, data)), TrainResult::Finished);
  return test::held_out_psnr(run, eval_data);
}

}  // namespace

TEST(LensTraining, DistortedCaptureTrainsAsWellAsThePinholeOne) {
  test::TempDir t;
  const test::IntraOpThreads threads(2);
  for (const char* lens : {"pinhole", "opencv"}) {
    SynthOptions o;
    o.res = 32;
    o.train_views = 24;
    o.test_views = 3;
    o.threads = 2;
    o.lens = lens;
    o.layout = "nerfstudio";
    write_synthetic_dataset(t / (std::string("data_") + lens), o);
  }
  // The distorted images with the lens left out of the json.
  std::filesystem::copy(t / "data_opencv", t / "data_ignored", std::filesystem::copy_options::recursive);
  auto j = nlohmann::json::parse(read_file(t / "data_ignored/transforms.json"));
  for (const char* k : {"k1", "k2", "p1", "p2"}) j.erase(k);
  j["camera_model"] = "PINHOLE";
  test::write_file(t / "data_ignored/transforms.json", j.dump());

  const std::string gt = t / "data_pinhole";
  const double pinhole = trained_psnr(gt, t / "run_pinhole", gt);
  const double lens = trained_psnr(t / "data_opencv", t / "run_opencv", gt);
  const double ignored = trained_psnr(t / "data_ignored", t / "run_ignored", gt);
  std::cout << "PSNR on the pinhole test views: trained on pinhole images " << pinhole << " dB, through the lens "
            << lens << " dB, lens ignored " << ignored << " dB" << std::endl;
  // Measured (2026-11-25, 2-core machine): 18.72 / 20.14 / 18.45 dB. Through the lens the views cover a
  // wider field, so that run may do better than the pinhole one; it must not do worse.
  EXPECT_GT(pinhole, 17.0);  // the scene was learnt (an untrained model gives ~10 dB)
  EXPECT_GT(lens, pinhole - 0.75);
  EXPECT_GT(lens, ignored + 0.75);
}
