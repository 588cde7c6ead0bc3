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

// One parameter of the release: its name there, ours, its shape.
struct ReleaseEntry {
  std::string release, ours;
  Shape shape;
};

// The release's parameters for the blender preset and the names they take here, written from
// docs/weights.md's tables.
std::vector<ReleaseEntry> release_map() {
  std::vector<ReleaseEntry> v;
  auto block = [&](const std::string& rel, const std::string& ours) {
    v.push_back({rel + ".attn.in_proj_weight", ours + ".attn.in_proj_weight", {576, 192}});
    v.push_back({rel + ".attn.in_proj_bias", ours + ".attn.in_proj_bias", {576}});
    v.push_back({rel + ".attn.out_proj.weight", ours + ".attn.out_proj.weight", {192, 192}});
    v.push_back({rel + ".attn.out_proj.bias", ours + ".attn.out_proj.bias", {192}});
    v.push_back({rel + ".ff_layer.0.weight", ours + ".ff_in.weight", {576, 192}});
    v.push_back({rel + ".ff_layer.0.bias", ours + ".ff_in.bias", {576}});
    v.push_back({rel + ".ff_layer.3.weight", ours + ".ff_out.weight", {192, 576}});
    v.push_back({rel + ".ff_layer.3.bias", ours + ".ff_out.bias", {192}});
    for (const char* n : {".norm1.weight", ".norm1.bias", ".norm2.weight", ".norm2.bias"})
      v.push_back({rel + n, ours + n, {192}});
  };
  v.push_back({"light_probes", "le", {1, 32, 192}});
  v.push_back({"color_token", "ray_token", {1, 1, 192}});
  v.push_back({"view_token.0.weight", "view_token.weight", {192, 27}});
  v.push_back({"view_token.0.bias", "view_token.bias", {192}});
  for (int i = 0; i < 4; ++i) {
    const std::string rel = "point_embedding." + std::to_string(2 * i),
                      ours = "volume_embedding.linear" + std::to_string(i);
    v.push_back({rel + ".weight", ours + ".weight", {192, i == 0 ? 96 : 192}});
    v.push_back({rel + ".bias", ours + ".bias", {192}});
  }
  for (int i = 0; i < 2; ++i) block("coarse.layers." + std::to_string(i), "coarse.blocks." + std::to_string(i));
  for (int i = 0; i < 6; ++i) block("fine.layers." + std::to_string(i), "fine.blocks." + std::to_string(i));
  for (const auto& [r, o] : std::vector<std::pair<std::string, std::string>>{{"c", "coarse"}, {"f", "fine"}}) {
    v.push_back({"rgb_" + r + "_diff.0.weight", "ray_head_" + o + ".linear.weight", {3, 192}});
    v.push_back({"rgb_" + r + "_diff.0.bias", "ray_head_" + o + ".linear.bias", {3}});
    block(r + "_spec_colour.cross_attn", "le_" + o + ".cross");
    block(r + "_spec_colour.self_attn.0", "le_" + o + ".self.0");
    block(r + "_spec_colour.self_attn.1", "le_" + o + ".self.1");
    block(r + "_spec_colour.decode", "le_" + o + ".decode");
    v.push_back({r + "_spec_rgb.0.weight", "le_head_" + o + ".hidden.weight", {192, 219}});
    v.push_back({r + "_spec_rgb.0.bias", "le_head_" + o + ".hidden.bias", {192}});
    v.push_back({r + "_spec_rgb.2.weight", "le_head_" + o + ".out.weight", {3, 192}});
    v.push_back({r + "_spec_rgb.2.bias", "le_head_" + o + ".out.bias", {3}});
  }
  return v;
}

std::vector<std::pair<std::string, Shape>> release_entries() {
  std::vector<std::pair<std::string, Shape>> v;
  for (const auto& e : release_map()) v.push_back({e.release, e.shape});
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
    // Every entry of the table in its own parameter, whole (the dict's entries are distinct random
    // tensors, so a swap of two same-shaped entries shows), and no parameter of ours left out.
    const auto map = release_map();
    EXPECT_EQ(map.size(), p.size());
    for (const auto& e : map) {
      ASSERT_TRUE(p.contains(e.ours)) << e.ours;
      EXPECT_TRUE(torch::equal(p[e.ours], dict.at(pre + e.release).toTensor())) << e.ours << " <- " << e.release;
    }
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
