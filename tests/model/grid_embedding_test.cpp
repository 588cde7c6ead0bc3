// The grid front end (model/grid_embedding.h): Zip-NeRF's per-level weights against their closed
// form, the features of a Gaussian as the grid's interpolation at its mean times those weights
// (computed here independently, in float64), zeros outside the cube, the cube of each scene kind,
// and the assembled model with model.embedding = "grid": its table, its gradient, the paper's model
// untouched, and the release's weights refused for it.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>

#include "kernels/hash_grid.h"
#include "model/able_nerf.h"
#include "model/grid_embedding.h"
#include "test_util.h"
#include "util/errors.h"
#include "data/data_config.h"
#include "model/model_config.h"

namespace ablenerf {
namespace {

ModelConfig grid_model() {
  ModelConfig m;
  m.width = 32;
  m.heads = 2;
  m.ff_ratio = 2;
  m.coarse_layers = 1;
  m.fine_layers = 1;
  m.samples = 8;
  m.le_count = 2;
  m.le_layers = 1;
  m.embedding = Embedding::Grid;
  m.grid_levels = 4;
  m.grid_features = 2;
  m.grid_log2_table = 8;
  m.grid_base_resolution = 2;
  m.grid_max_resolution = 32;
  m.grid_ipe_degrees = 2;
  m.grid_lr_scale = 10;
  m.grid_bound = 1.5;
  return m;
}

TEST(GridEmbedding, LevelWeightsAreZipNerfsErf) {
  const auto res = torch::tensor({2.f, 16.f, 128.f});
  const auto sigma2 = torch::tensor({0.f, 1e-6f, 1.f / (8 * 16 * 16), 0.01f});
  const auto w = grid_level_weights(sigma2, res);
  ASSERT_EQ(w.sizes(), (std::vector<int64_t>{4, 3}));
  for (int i = 0; i < 4; ++i)
    for (int l = 0; l < 3; ++l) {
      const double s2 = sigma2[i].item<double>(), n = res[l].item<double>();
      const double want = s2 == 0 ? 1.0 : std::erf(1 / std::sqrt(8 * s2 * n * n));
      EXPECT_NEAR(w[i][l].item<double>(), want, 1e-6) << i << " " << l;
    }
  // A Gaussian whose sigma is 1/sqrt(8) of a level's cell: erf(1) at that level.
  EXPECT_NEAR(w[2][1].item<double>(), std::erf(1.0), 1e-6);
  // Wider Gaussians and finer levels weigh less.
  EXPECT_GT(w[1][2].item<float>(), w[3][2].item<float>());
  EXPECT_GT(w[3][0].item<float>(), w[3][2].item<float>());
}

TEST(GridEmbedding, FeaturesAreTheGridAtTheMeanTimesTheLevelWeights) {
  torch::manual_seed(3);
  const ModelConfig m = grid_model();
  GridEmbedding grid(m, GridCube{-1.5, 1.5});
  {
    torch::NoGradGuard no_grad;  // a table with features of order 1, not the 1e-4 of the start
    for (auto& p : grid->parameters()) p.uniform_(-0.1, 0.1);
  }
  auto gen = at::detail::createCPUGenerator(4);
  const auto mean = torch::rand({5, 3, 3}, gen) * 2.8 - 1.4;  // inside the cube
  const auto cov = torch::rand({5, 3, 3}, gen) * 1e-2 + 1e-5;
  const auto got = grid(mean, cov);
  ASSERT_EQ(got.sizes(), (std::vector<int64_t>{5, 3, 8}));
  // Independently: the reference lookup of table() at the mean mapped to the unit cube, each level
  // times erf(1 / sqrt(8 s2 n^2)) with s2 the mean per-axis variance over the cube's side squared.
  const auto unit = ((mean.reshape({-1, 3}) + 1.5) / 3.0).contiguous();
  const auto raw = hash_grid_encode_reference(unit, grid->table().detach(), grid->shape()).to(torch::kDouble);
  const auto c = cov.reshape({-1, 3}).to(torch::kDouble);
  for (int64_t i = 0; i < unit.size(0); ++i)
    for (int l = 0; l < m.grid_levels; ++l) {
      const double s2 = c[i].mean().item<double>() / 9.0, n = grid->shape().resolution[l];
      const double w = std::erf(1 / std::sqrt(8 * s2 * n * n));
      for (int f = 0; f < m.grid_features; ++f)
        EXPECT_NEAR(got.reshape({-1, 8})[i][l * 2 + f].item<double>(), w * raw[i][l][f].item<double>(), 1e-6);
    }
}

// The entries lookups reach, by hand: a table of 64 rows of 2 floats; level 0 (2 cells, 3^3 = 27
// vertices) dense, level 1 (3 cells, 4^3 = 64) dense and full, level 2 (40 cells) hashed: entries
// [0, 54) and [128, 384), levels 1 and 2 joined. Every entry a lookup's gradient writes lies in them.
TEST(GridEmbedding, TableEntriesReadAreTheDenseLevelsVerticesAndTheHashedLevels) {
  HashGridShape shape;
  shape.levels = 3;
  shape.features = 2;
  shape.table_size = 64;
  shape.resolution[0] = 2;
  shape.resolution[1] = 3;
  shape.resolution[2] = 40;
  GridEmbedding g(shape, GridCube{-1, 1}, 1.0);
  const IndexRanges want{{0, 54}, {128, 384}};
  EXPECT_EQ(g->table_entries_read(), want);
  const auto mean = (torch::rand({500, 3}) * 2.2 - 1.1).requires_grad_(false);
  g->forward(mean, torch::full({500, 3}, 1e-6)).pow(2).sum().backward();
  const auto grad = g->table_parameter().grad().reshape({-1});
  const auto outside = torch::ones({384}, torch::kBool);
  for (const auto& r : want) outside.slice(0, r.first, r.second).fill_(false);
  EXPECT_EQ(grad.masked_select(outside).abs().max().item<float>(), 0.f);
  EXPECT_GT(grad.slice(0, 0, 54).abs().max().item<float>(), 0.f);
}

TEST(GridEmbedding, SamplesOutsideTheCubeReadZeros) {
  const ModelConfig m = grid_model();
  GridEmbedding grid(m, GridCube{-1.5, 1.5});
  const auto mean = torch::tensor({0.f, 0.f, 0.f, 1.6f, 0.f, 0.f, 0.f, -2.f, 0.f}).view({3, 3});
  const auto out = grid(mean, torch::full({3, 3}, 1e-6f));
  EXPECT_GT(out[0].abs().max().item<float>(), 0.f);
  EXPECT_EQ(out[1].abs().max().item<float>(), 0.f);
  EXPECT_EQ(out[2].abs().max().item<float>(), 0.f);
}

TEST(GridEmbedding, CubeOfEachSceneKind) {
  ModelConfig m = grid_model();
  m.grid_bound = 2.5;
  EXPECT_DOUBLE_EQ(grid_cube(m, SceneKind::Bounded).hi, 2.5);
  EXPECT_DOUBLE_EQ(grid_cube(m, SceneKind::Auto).lo, -2.5);
  EXPECT_DOUBLE_EQ(grid_cube(m, SceneKind::Unbounded).hi, 2.0);  // the contracted ball's radius
  EXPECT_DOUBLE_EQ(grid_cube(m, SceneKind::ForwardFacing).lo, -1.0);
}

TEST(GridEmbedding, ModelWithTheGridTrainsItsTable) {
  torch::manual_seed(5);
  const ModelConfig m = grid_model();
  AbleNerf model(m, SceneKind::Unbounded);
  const auto params = model->named_parameters();
  ASSERT_TRUE(params.contains("grid.table"));
  EXPECT_EQ(params["grid.table"].sizes(), (std::vector<int64_t>{4, 256, 2}));
  // levels * features of the grid and 6 per IPE degree beside them
  EXPECT_EQ(params["volume_embedding.linear0.weight"].size(1), 8 + 6 * 2);
  const auto out = model->forward(test::random_rays(16, 6), 0.1, 100.0);
  EXPECT_TRUE(torch::isfinite(out.rgb_fine).all().item<bool>());
  out.rgb_fine.sum().backward();
  EXPECT_GT(params["grid.table"].grad().abs().max().item<float>(), 0.f);

  ModelConfig grid_alone = m;
  grid_alone.grid_ipe_degrees = 0;
  EXPECT_EQ(AbleNerf(grid_alone)->named_parameters()["volume_embedding.linear0.weight"].size(1), 8);

  ModelConfig ipe = m;
  ipe.embedding = Embedding::Ipe;
  AbleNerf paper(ipe);
  EXPECT_FALSE(paper->named_parameters().contains("grid.table"));
  EXPECT_EQ(paper->named_parameters()["volume_embedding.linear0.weight"].size(1), 6 * ipe.ipe_degrees);
}

TEST(GridEmbedding, ReleaseWeightsAreRefusedForAGridModel) {
  AbleNerf model(grid_model());
  c10::impl::GenericDict dict(c10::StringType::get(), c10::TensorType::get());
  try {
    import_release_weights(model, dict, "release.pt");
    ADD_FAILURE() << "not refused";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("model.embedding"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace ablenerf
