// Checkpoints: exact round trip, and truncated / corrupted / foreign files are refused.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <filesystem>
#include <fstream>

#include "train/checkpoint.h"
#include "train_fixture.h"
#include "util/errors.h"
#include "model/model_config.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

struct Fixture {
  Config config = test::tiny_config();
  AbleNerf model{config.get<ModelConfig>()};
  torch::optim::Adam optim{model->parameters(), torch::optim::AdamOptions(1e-3)};
  Fixture() {
    // one real step so that Adam has state to save
    auto out = model->forward(test::random_rays(4, 5), 2.0, 6.0);
    (out.rgb_fine.sum() + out.rgb_coarse.sum()).backward();
    optim.step();
  }
};

std::string expect_refused(const std::string& path, Fixture& f) {
  try {
    load_checkpoint(path, f.config, f.model, f.optim);
  } catch (const InputError& e) {
    return e.what();
  }
  ADD_FAILURE() << "checkpoint was not refused";
  return "";
}

}  // namespace

TEST(Checkpoint, RoundTripIsExact) {
  test::TempDir t;
  Fixture a;
  TrainState st;
  st.step = 42;
  st.elapsed_seconds = 3.5;
  st.rng_state = at::detail::createCPUGenerator(9).get_state();
  save_checkpoint(t / "c.pt", a.config, a.model, a.optim, st);
  Fixture b;  // different random init
  TrainState back = load_checkpoint(t / "c.pt", b.config, b.model, b.optim);
  EXPECT_EQ(back.step, 42);
  EXPECT_DOUBLE_EQ(back.elapsed_seconds, 3.5);
  EXPECT_TRUE(torch::equal(back.rng_state, st.rng_state));
  auto pa = a.model->named_parameters(), pb = b.model->named_parameters();
  for (const auto& kv : pa) EXPECT_TRUE(torch::equal(kv.value(), pb[kv.key()])) << kv.key();
  // Adam moments too: one more identical step keeps the two models identical
  for (auto* f : {&a, &b}) {
    f->optim.zero_grad();
    for (auto& p : f->model->parameters()) p.mutable_grad() = torch::ones_like(p);
    f->optim.step();
  }
  for (const auto& kv : a.model->named_parameters()) EXPECT_TRUE(torch::equal(kv.value(), pb[kv.key()])) << kv.key();
}

TEST(Checkpoint, TruncatedCorruptedAndForeignAreRefused) {
  test::TempDir t;
  Fixture f;
  TrainState st;
  st.rng_state = at::detail::createCPUGenerator(1).get_state();
  save_checkpoint(t / "c.pt", f.config, f.model, f.optim, st);
  const auto size = fs::file_size(t / "c.pt");

  fs::copy_file(t / "c.pt", t / "trunc.pt");
  fs::resize_file(t / "trunc.pt", size - 100);
  EXPECT_NE(expect_refused(t / "trunc.pt", f).find("length"), std::string::npos);

  fs::copy_file(t / "c.pt", t / "flip.pt");
  {
    std::fstream io(t / "flip.pt", std::ios::in | std::ios::out | std::ios::binary);
    io.seekp(static_cast<std::streamoff>(size / 2));
    char c;
    io.seekg(static_cast<std::streamoff>(size / 2));
    io.get(c);
    io.seekp(static_cast<std::streamoff>(size / 2));
    io.put(static_cast<char>(c ^ 0x5a));
  }
  EXPECT_NE(expect_refused(t / "flip.pt", f).find("checksum"), std::string::npos);

  test::write_file(t / "junk.pt", "PK\x03\x04 not ours");
  EXPECT_NE(expect_refused(t / "junk.pt", f).find("not an ablenerf checkpoint"), std::string::npos);

  Config other = f.config;
  other.set("model.le_count=3");
  AbleNerf m2(other.get<ModelConfig>());
  torch::optim::Adam o2(m2->parameters(), torch::optim::AdamOptions(1e-3));
  try {
    load_checkpoint(t / "c.pt", other, m2, o2);
    ADD_FAILURE() << "config mismatch not detected";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("model.le_count"), std::string::npos) << e.what();
  }
}
