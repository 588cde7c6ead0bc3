// Weight files: save/load round trip, and import of a state dict with the authors' names
// (docs/weights.md), built here from that table by hand with random tensors.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <fstream>

#include "model/able_nerf.h"
#include "test_util.h"
#include "util/errors.h"
#include "model/model_config.h"

namespace ablenerf {
namespace {

using Shape = std::vector<int64_t>;

// The release's parameter names and shapes for the blender preset, written from docs/weights.md.
std::vector<std::pair<std::string, Shape>> release_entries() {
  std::vector<std::pair<std::string, Shape>> v;
  auto block = [&](const std::string& p) {
    v.push_back({p + ".attn.in_proj_weight", {576, 192}});
    v.push_back({p + ".attn.in_proj_bias", {576}});
    v.push_back({p + ".attn.out_proj.weight", {192, 192}});
    v.push_back({p + ".attn.out_proj.bias", {192}});
    v.push_back({p + ".ff_layer.0.weight", {576, 192}});
    v.push_back({p + ".ff_layer.0.bias", {576}});
    v.push_back({p + ".ff_layer.3.weight", {192, 576}});
    v.push_back({p + ".ff_layer.3.bias", {192}});
    for (const char* n : {".norm1.weight", ".norm1.bias", ".norm2.weight", ".norm2.bias"}) v.push_back({p + n, {192}});
  };
  v.push_back({"light_probes", {1, 32, 192}});
  v.push_back({"color_token", {1, 1, 192}});
  v.push_back({"view_token.0.weight", {192, 27}});
  v.push_back({"view_token.0.bias", {192}});
  v.push_back({"point_embedding.0.weight", {192, 96}});
  for (int i : {2, 4, 6}) v.push_back({"point_embedding." + std::to_string(i) + ".weight", {192, 192}});
  for (int i : {0, 2, 4, 6}) v.push_back({"point_embedding." + std::to_string(i) + ".bias", {192}});
  for (int i = 0; i < 2; ++i) block("coarse.layers." + std::to_string(i));
  for (int i = 0; i < 6; ++i) block("fine.layers." + std::to_string(i));
  for (const std::string p : {"rgb_c_diff.0", "rgb_f_diff.0"}) {
    v.push_back({p + ".weight", {3, 192}});
    v.push_back({p + ".bias", {3}});
  }
  for (const std::string p : {"c_", "f_"}) {
    block(p + "spec_colour.cross_attn");
    block(p + "spec_colour.self_attn.0");
    block(p + "spec_colour.self_attn.1");
    block(p + "spec_colour.decode");
    v.push_back({p + "spec_rgb.0.weight", {192, 219}});
    v.push_back({p + "spec_rgb.0.bias", {192}});
    v.push_back({p + "spec_rgb.2.weight", {3, 192}});
    v.push_back({p + "spec_rgb.2.bias", {3}});
  }
  return v;
}

c10::Dict<c10::IValue, c10::IValue> release_dict(bool lightning_prefix) {
  torch::manual_seed(42);
  c10::impl::GenericDict d(c10::StringType::get(), c10::TensorType::get());
  const std::string prefix = lightning_prefix ? "model." : "";
  for (const auto& [name, shape] : release_entries()) d.insert(prefix + name, torch::randn(shape));
  d.insert(prefix + "dir_query.0.weight", torch::randn({192, 27}));  // unused layer: ignored
  d.insert(prefix + "dir_query.0.bias", torch::randn({192}));
  return d;
}

void write_bytes(const std::string& path, const std::vector<char>& bytes) {
  std::ofstream out(path, std::ios::binary);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

std::string import_error(c10::Dict<c10::IValue, c10::IValue> d) {
  AbleNerf model{ModelConfig{}};
  try {
    import_release_weights(model, d, "w.pt");
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(Weights, SaveLoadRoundTripsExactly) {
  test::TempDir dir;
  ModelConfig cfg;
  cfg.width = 32;
  cfg.heads = 2;
  cfg.samples = 8;
  cfg.le_count = 4;
  torch::manual_seed(1);
  AbleNerf a(cfg);
  torch::manual_seed(2);
  AbleNerf b(cfg);
  save_weights(a, dir / "w.pt");
  load_weights(b, dir / "w.pt");
  const auto pa = a->named_parameters(), pb = b->named_parameters();
  ASSERT_EQ(pa.size(), pb.size());
  for (const auto& p : pa) EXPECT_TRUE(torch::equal(p.value(), pb[p.key()])) << p.key();
  // A model of another shape refuses the file, naming the parameter.
  cfg.width = 48;
  cfg.heads = 3;
  AbleNerf c(cfg);
  EXPECT_THROW(load_weights(c, dir / "w.pt"), InputError);
}

TEST(Weights, ReleaseDictionaryLandsInTheRightParameters) {
  test::TempDir dir;
  for (bool prefix : {false, true}) {
    const auto dict = release_dict(prefix);
    write_bytes(dir / "release.pt", torch::pickle_save(c10::IValue(dict)));
    AbleNerf model{ModelConfig{}};
    import_release_weights(model, read_weights_dict(dir / "release.pt"), dir / "release.pt");
    const auto p = model->named_parameters();
    const std::string pre = prefix ? "model." : "";
    auto rel = [&](const std::string& n) { return dict.at(pre + n).toTensor(); };
    EXPECT_TRUE(torch::equal(p["le"], rel("light_probes")));
    EXPECT_TRUE(torch::equal(p["ray_token"], rel("color_token")));
    EXPECT_TRUE(torch::equal(p["volume_embedding.linear3.weight"], rel("point_embedding.6.weight")));
    EXPECT_TRUE(torch::equal(p["fine.blocks.5.ff_out.weight"], rel("fine.layers.5.ff_layer.3.weight")));
    EXPECT_TRUE(torch::equal(p["coarse.blocks.1.attn.in_proj_weight"], rel("coarse.layers.1.attn.in_proj_weight")));
    EXPECT_TRUE(torch::equal(p["le_fine.self.1.norm2.bias"], rel("f_spec_colour.self_attn.1.norm2.bias")));
    EXPECT_TRUE(
        torch::equal(p["le_coarse.decode.attn.out_proj.weight"], rel("c_spec_colour.decode.attn.out_proj.weight")));
    EXPECT_TRUE(torch::equal(p["le_head_fine.hidden.weight"], rel("f_spec_rgb.0.weight")));
    EXPECT_TRUE(torch::equal(p["ray_head_coarse.linear.bias"], rel("rgb_c_diff.0.bias")));
    EXPECT_TRUE(torch::equal(p["view_token.weight"], rel("view_token.0.weight")));
    // Every parameter was overwritten: the sum over the model equals the sum over the dict.
    double model_sum = 0, dict_sum = 0;
    for (const auto& q : p) model_sum += q.value().sum().item<double>();
    for (const auto& [name, shape] : release_entries()) dict_sum += rel(name).sum().item<double>();
    EXPECT_NEAR(model_sum, dict_sum, 1e-6 * std::abs(dict_sum) + 1e-3);
  }
}

TEST(Weights, ReleaseMismatchesAreNamed) {
  auto wrong = release_dict(false);
  wrong.insert_or_assign("coarse.layers.0.attn.in_proj_weight", torch::zeros({192, 576}));
  EXPECT_EQ(import_error(wrong), "w.pt: coarse.layers.0.attn.in_proj_weight: expected shape [576, 192] got [192, 576]");
  auto missing = release_dict(false);
  ASSERT_EQ(missing.erase("f_spec_rgb.2.bias"), 1u);
  EXPECT_EQ(import_error(missing), "w.pt: f_spec_rgb.2.bias: missing");
  auto extra = release_dict(false);
  extra.insert("fine.layers.6.norm1.weight", torch::zeros({192}));
  EXPECT_EQ(import_error(extra), "w.pt: fine.layers.6.norm1.weight: unexpected parameter");
}

}  // namespace
}  // namespace ablenerf
