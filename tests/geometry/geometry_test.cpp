// Geometry out (geometry/*.h) against analytic surfaces, independent of any trained model: depth
// maps of a sphere written by hand from the pinhole model become points on the sphere; the same
// depth maps from cameras all round fuse (TSDF, marching cubes) into a mesh on the sphere; Poisson
// reconstruction of its oriented points too; points come back in the capture's frame; outliers go,
// thinning keeps at most what is asked, normals face the cameras; files are written whole or not
// at all.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <limits>
#include <filesystem>
#include <sstream>

#include "data/ply.h"
#include "geometry/depth_points.h"
#include "geometry/fuse.h"
#include "geometry/preview.h"
#include "geometry/surface_score.h"
#include "test_util.h"
#include "util/errors.h"

namespace ablenerf {
namespace {

constexpr double kRadius = 0.6;
const std::array<double, 3> kCentre{0.1, -0.05, 0.2};

// A pinhole camera at `eye` looking at kCentre (OpenGL axes: the camera looks down its -z), world
// up +z unless looking along it. (3,4) camera-to-world.
torch::Tensor look_at_sphere(const std::array<double, 3>& eye) {
  auto sub = [](std::array<double, 3> a, std::array<double, 3> b) {
    return std::array<double, 3>{a[0] - b[0], a[1] - b[1], a[2] - b[2]};
  };
  auto norm = [](std::array<double, 3> a) {
    const double n = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    return std::array<double, 3>{a[0] / n, a[1] / n, a[2] / n};
  };
  auto cross = [](std::array<double, 3> a, std::array<double, 3> b) {
    return std::array<double, 3>{a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
  };
  const auto back = norm(sub(eye, kCentre));  // camera +z points away from what it sees
  const std::array<double, 3> up0 =
      std::abs(back[2]) > 0.99 ? std::array<double, 3>{0, 1, 0} : std::array<double, 3>{0, 0, 1};
  const auto right = norm(cross(up0, back));
  const auto up = cross(back, right);
  auto m = torch::zeros({3, 4}, torch::kDouble);
  for (int r = 0; r < 3; ++r) {
    m[r][0] = right[static_cast<size_t>(r)];
    m[r][1] = up[static_cast<size_t>(r)];
    m[r][2] = back[static_cast<size_t>(r)];
    m[r][3] = eye[static_cast<size_t>(r)];
  }
  return m;
}

Intrinsics sphere_camera(int side) {
  Intrinsics k;
  k.width = k.height = side;
  k.fx = k.fy = 1.1 * side;
  k.cx = k.cy = 0.5 * side;
  return k;
}

// Depth along the optical axis of every pixel centre that sees the sphere (0 elsewhere), from the
// pinhole model and the ray-sphere intersection, written out here rather than taken from rays.h.
torch::Tensor sphere_depth(const torch::Tensor& c2w, const Intrinsics& k) {
  auto depth = torch::zeros({k.height, k.width}, torch::kFloat);
  auto d = depth.accessor<float, 2>();
  const auto m = c2w.accessor<double, 2>();
  const double ox = m[0][3] - kCentre[0], oy = m[1][3] - kCentre[1], oz = m[2][3] - kCentre[2];
  for (int v = 0; v < k.height; ++v)
    for (int u = 0; u < k.width; ++u) {
      // Camera direction with z = -1 (OpenGL: image y down is camera -y).
      const double cx = (u + 0.5 - k.cx) / k.fx, cy = -(v + 0.5 - k.cy) / k.fy, cz = -1;
      const double dx = m[0][0] * cx + m[0][1] * cy + m[0][2] * cz;
      const double dy = m[1][0] * cx + m[1][1] * cy + m[1][2] * cz;
      const double dz = m[2][0] * cx + m[2][1] * cy + m[2][2] * cz;
      // |o + t d|^2 = R^2: the nearer root; t is the depth because the direction's camera z is -1.
      const double a = dx * dx + dy * dy + dz * dz, b = 2 * (ox * dx + oy * dy + oz * dz);
      const double c = ox * ox + oy * oy + oz * oz - kRadius * kRadius, disc = b * b - 4 * a * c;
      if (disc > 0) d[v][u] = static_cast<float>((-b - std::sqrt(disc)) / (2 * a));
    }
  return depth;
}

// Distance of each row of xyz (N,3) from the sphere's surface.
torch::Tensor off_sphere(const torch::Tensor& xyz) {
  const auto c = torch::tensor({kCentre[0], kCentre[1], kCentre[2]}, torch::kDouble);
  return ((xyz.to(torch::kDouble) - c).norm(2, -1) - kRadius).abs();
}

std::vector<std::array<double, 3>> cameras_all_round(int n) {
  std::vector<std::array<double, 3>> eyes;
  for (int i = 0; i < n; ++i) {
    // A golden-angle spiral over the whole sphere of directions, distance 2.5.
    const double z = 1 - (2.0 * i + 1) / n, r = std::sqrt(1 - z * z), phi = i * 2.399963229728653;
    eyes.push_back({kCentre[0] + 2.5 * r * std::cos(phi), kCentre[1] + 2.5 * r * std::sin(phi), kCentre[2] + 2.5 * z});
  }
  return eyes;
}

// The sphere's points seen by `cameras` 40x40 cameras all round, and each point's camera centre.
std::pair<PointSet, torch::Tensor> sphere_points_all_round(int cameras) {
  const Intrinsics k = sphere_camera(40);
  std::vector<PointSet> sets;
  std::vector<torch::Tensor> eyes;
  const CropBox all{{-10, -10, -10}, {10, 10, 10}};
  for (const auto& eye : cameras_all_round(cameras)) {
    const auto c2w = look_at_sphere(eye);
    PointSet p = points_from_depth(c2w, k, sphere_depth(c2w, k), torch::full({40, 40, 3}, 0.5), 0.1, 10, all);
    eyes.push_back(torch::tensor({eye[0], eye[1], eye[2]}, torch::kFloat).expand({p.size(), 3}));
    sets.push_back(p);
  }
  return {concat_points(sets), torch::cat(eyes)};
}

TEST(Geometry, DepthOfASphereBecomesPointsOnIt) {
  const Intrinsics k = sphere_camera(48);
  const auto c2w = look_at_sphere({2.0, -1.0, 1.2});
  const auto depth = sphere_depth(c2w, k);
  const auto rgb = torch::full({48, 48, 3}, 0.5);
  CropBox all{{-10, -10, -10}, {10, 10, 10}};
  const PointSet p = points_from_depth(c2w, k, depth, rgb, 0.1, 10.0, all);
  ASSERT_EQ(p.size(), (depth > 0).sum().item<int64_t>());
  ASSERT_GT(p.size(), 300);
  EXPECT_LT(off_sphere(p.xyz).max().item<double>(), 1e-5);
  // The crop box and the depth range drop what lies outside them; `keep` drops what it says.
  CropBox upper{{-10, -10, kCentre[2]}, {10, 10, 10}};
  const PointSet up = points_from_depth(c2w, k, depth, rgb, 0.1, 10.0, upper);
  EXPECT_GT(up.size(), 0);
  EXPECT_LT(up.size(), p.size());
  EXPECT_GE(up.xyz.select(1, 2).min().item<double>(), kCentre[2]);
  const PointSet none = points_from_depth(c2w, k, depth, rgb, 0.1, 1.0, all);  // the sphere is beyond 1
  EXPECT_EQ(none.size(), 0);
  auto keep = torch::zeros({48, 48}, torch::kBool);
  keep.slice(0, 0, 24).fill_(true);
  EXPECT_EQ(points_from_depth(c2w, k, depth, rgb, 0.1, 10.0, all, keep).size(),
            (depth.slice(0, 0, 24) > 0).sum().item<int64_t>());
}

TEST(Geometry, PointsComeBackInTheCapturesFrame) {
  SceneFrame f;
  const double a = 0.7;  // a rotation about (1,1,1)/sqrt(3), a shift and a scale
  const double c = std::cos(a), s = std::sin(a), t = 1 - c, u = 1 / std::sqrt(3.0);
  f.rotation = {t * u * u + c,     t * u * u - s * u, t * u * u + s * u, t * u * u + s * u, t * u * u + c,
                t * u * u - s * u, t * u * u - s * u, t * u * u + s * u, t * u * u + c};
  f.centre = {1.5, -2.0, 0.25};
  f.scale = 0.37;
  const std::vector<std::array<double, 3>> pts{{0, 0, 0}, {1, 2, 3}, {-4, 0.5, 2}};
  std::vector<double> flat;
  for (const auto& p : pts) {
    const auto q = f.point_to_scene(p);
    flat.insert(flat.end(), q.begin(), q.end());
  }
  const auto back = points_to_capture(torch::tensor(flat, torch::kDouble).reshape({3, 3}), f);
  for (size_t i = 0; i < pts.size(); ++i)
    for (size_t j = 0; j < 3; ++j)
      EXPECT_NEAR(back[static_cast<int64_t>(i)][static_cast<int64_t>(j)].item<double>(), pts[i][j], 1e-12);
}

TEST(Geometry, CropBoxParsing) {
  const CropBox b = CropBox::parse("-1,-2,-3,1,2,3.5", "--crop");
  EXPECT_EQ(b.lo[1], -2);
  EXPECT_EQ(b.hi[2], 3.5);
  EXPECT_TRUE(b.contains({0, 0, 0}));
  EXPECT_FALSE(b.contains({0, 0, 3.6}));
  for (const char* bad : {"1,2,3", "a,0,0,1,1,1", "0,0,0,1,1,0", "0,0,0,1,1,nan", "0,0,0,1,1,1,1"}) {
    try {
      CropBox::parse(bad, "--crop");
      ADD_FAILURE() << bad;
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("--crop"), std::string::npos) << e.what();
    }
  }
}

TEST(Geometry, TsdfOfSphereDepthMapsIsTheSphere) {
  const Intrinsics k = sphere_camera(64);
  std::vector<DepthView> views;
  for (const auto& eye : cameras_all_round(24)) {
    const auto c2w = look_at_sphere(eye);
    views.push_back({c2w, sphere_depth(c2w, k), torch::full({64, 64, 3}, 0.25), k});
  }
  TsdfOptions o;
  o.voxel = 0.02;
  o.truncation = 0.08;
  o.crop = CropBox{{-2, -2, -2}, {2, 2, 2}};
  const Mesh m = fuse_tsdf(views, o);
  ASSERT_GT(m.triangle_count(), 1000);
  // The vertices on the surface to a fraction of a voxel (the depth maps' pixels, ~0.03 wide at the
  // sphere, are coarser than the voxels: the worst, at grazing views, within 1.5 voxels); and the surface covered all
  // round (vertices in every octant around the centre).
  const auto off = off_sphere(m.vertices);
  std::cout << "TSDF vertices off the sphere: median " << off.median().item<double>() << ", 99% "
            << off.quantile(0.99).item<double>() << ", max " << off.max().item<double>() << " (voxel " << o.voxel << ")"
            << std::endl;
  EXPECT_LT(off.median().item<double>(), 0.4 * o.voxel);
  EXPECT_LT(off.quantile(0.99).item<double>(), o.voxel);
  EXPECT_LT(off.max().item<double>(), 1.5 * o.voxel);
  const auto c = torch::tensor({kCentre[0], kCentre[1], kCentre[2]}, torch::kDouble);
  const auto rel = m.vertices - c;
  for (int oct = 0; oct < 8; ++oct) {
    auto in = torch::ones({m.vertex_count()}, torch::kBool);
    for (int a = 0; a < 3; ++a) in = in & ((oct >> a) & 1 ? rel.select(1, a) > 0.2 : rel.select(1, a) < -0.2);
    EXPECT_GT(in.sum().item<int64_t>(), 0) << "octant " << oct;
  }
  ASSERT_TRUE(m.colours.defined());
  EXPECT_NEAR(m.colours.mean().item<double>(), 0.25, 0.01);
  // A crop box through the middle keeps only the triangles inside it.
  o.crop = CropBox{{-2, -2, kCentre[2]}, {2, 2, 2}};
  const Mesh half = fuse_tsdf(views, o);
  EXPECT_LT(half.triangle_count(), m.triangle_count() * 0.6);
  EXPECT_GE(half.vertices.select(1, 2).min().item<double>(), kCentre[2] - 1e-9);
}

TEST(Geometry, CleaningDropsOutliersThinsAndFacesNormalsToTheCameras) {
  auto [p, eyes] = sphere_points_all_round(8);
  // Ten stray points far off the surface.
  const auto stray = torch::tensor({3.0, 3.0, 3.0}, torch::kFloat) + torch::rand({10, 3}) * 0.5;
  p.xyz = torch::cat({p.xyz, stray});
  p.rgb = torch::cat({p.rgb, torch::zeros({10, 3})});
  auto eye = torch::cat({eyes, torch::zeros({10, 3})});
  const PointSet clean = clean_points(p, 2000, 20, 2.0, eye);
  ASSERT_GT(clean.size(), 500);
  EXPECT_LE(clean.size(), 2000);
  EXPECT_LT(off_sphere(clean.xyz).max().item<double>(), 1e-3);  // the strays are gone
  // Normals: unit, radial, outwards (every camera is outside the sphere).
  ASSERT_TRUE(clean.normals.defined());
  const auto c = torch::tensor({kCentre[0], kCentre[1], kCentre[2]}, torch::kFloat);
  const auto radial = (clean.xyz - c) / (clean.xyz - c).norm(2, -1, true);
  const auto cosine = (clean.normals * radial).sum(-1);
  EXPECT_GT(cosine.min().item<double>(), 0.9);
}

TEST(Geometry, PoissonOfOrientedSpherePointsIsTheSphere) {
  const auto [points, eyes] = sphere_points_all_round(12);
  const PointSet clean = clean_points(points, 20000, 20, 2.0, eyes);
  const CropBox all{{-10, -10, -10}, {10, 10, 10}};
  const Mesh m = poisson_mesh(clean, 7, 0.02, all);
  ASSERT_GT(m.triangle_count(), 500);
  // Poisson smooths: within 2% of the radius, nearly everywhere.
  const auto off = off_sphere(m.vertices);
  EXPECT_LT(off.quantile(0.98).item<double>(), 0.02 * kRadius);
}

TEST(Geometry, FilesAreWrittenWholeOrNotAtAll) {
  test::TempDir t;
  PointSet p{torch::rand({50, 3}), torch::rand({50, 3}), {}};
  write_points(p, t / "points.ply");
  const auto back = read_ply_points(t / "points.ply");
  ASSERT_EQ(back.size(), 50u);
  EXPECT_NEAR(back[7][1], p.xyz[7][1].item<double>(), 1e-6);
  // A missing folder: an environment error, and nothing written.
  EXPECT_THROW(write_points(p, t / "no/such/points.ply"), EnvironmentError);
  EXPECT_FALSE(std::filesystem::exists(t / "no"));
  // An extension the writers do not know: bad input naming the path.
  try {
    write_points(p, t / "points.xyz");
    ADD_FAILURE() << "a .xyz point file was written";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("points.xyz"), std::string::npos);
  }
  Mesh m;
  m.vertices = torch::tensor({0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0}, torch::kDouble).reshape({3, 3});
  m.triangles = torch::tensor({0, 1, 2}, torch::kLong).reshape({1, 3});
  for (const char* name : {"m.ply", "m.obj", "m.glb"}) {
    write_mesh(m, t / name);
    EXPECT_GT(std::filesystem::file_size(t / name), 0u) << name;
  }
  // An earlier file survives a failed write over it.
  const auto size = std::filesystem::file_size(t / "m.ply");
  EXPECT_THROW(write_mesh(m, t / "m.stl2"), InputError);
  EXPECT_EQ(std::filesystem::file_size(t / "m.ply"), size);
  // No temporary (util/fs.h's atomic_temp_prefix names) is left behind.
  for (const auto& e : std::filesystem::directory_iterator(t.path()))
    EXPECT_EQ(e.path().filename().string().find(".tmp"), std::string::npos) << e.path();
}

// Scoring against known spheres: their own dense samples score F = 1; the same moved off the surface
// by twice the threshold score 0; half of the visible surface gives recall 1/2; a sample hidden
// behind another sphere is not asked for.
TEST(SurfaceScore, PrecisionRecallAndVisibilityOnKnownSpheres) {
  const std::vector<synth::SphereTruth> spheres{{"a", "diffuse", {0, 0, 0}, 0.5}, {"b", "glass", {3, 0, 0}, 0.5}};
  // Cameras all round, far away: every sample is seen.
  const auto eyes = torch::tensor({10.0, 0.0, 0.0,  -10.0, 0.0, 0.0,   0.0, 10.0, 0.0,  0.0, -10.0, 0.0,
                                   0.0,  0.0, 10.0, 0.0,   0.0, -10.0, 1.5, 0.0,  10.0, 1.5, 0.0,   -10.0},
                                  torch::kDouble)
                        .reshape({8, 3});
  const auto [truth, owner] = visible_sphere_samples(spheres, eyes, 4000);
  EXPECT_EQ(truth.size(0), 8000);
  const double tau = 0.02;
  auto exact = score_against_spheres(truth, spheres, eyes, tau, 4000);
  EXPECT_DOUBLE_EQ(exact["all"]["fscore"].get<double>(), 1.0);
  EXPECT_NEAR(exact["all"]["accuracy_mean"].get<double>(), 0.0, 1e-12);
  EXPECT_EQ(exact["b"]["material"], "glass");
  // Pushed 2 tau outwards: nothing is within tau either way.
  const auto centre =
      torch::stack({torch::tensor({0.0, 0.0, 0.0}, torch::kDouble), torch::tensor({3.0, 0.0, 0.0}, torch::kDouble)})
          .index_select(0, owner);
  const auto out = centre + (truth - centre) * ((0.5 + 2 * tau) / 0.5);
  auto off = score_against_spheres(out, spheres, eyes, tau, 4000);
  EXPECT_EQ(off["all"]["precision"].get<double>(), 0.0);
  EXPECT_EQ(off["all"]["recall"].get<double>(), 0.0);
  EXPECT_NEAR(off["all"]["accuracy_mean"].get<double>(), 2 * tau, 1e-9);
  // Only sphere a's upper half given: a's recall about 1/2, b's 0; precision 1.
  const auto upper = ((owner == 0) & (truth.select(1, 2) > 0)).nonzero().squeeze(-1);
  auto half = score_against_spheres(truth.index_select(0, upper), spheres, eyes, tau, 4000);
  EXPECT_NEAR(half["a"]["recall"].get<double>(), 0.5, 0.02);
  EXPECT_EQ(half["b"]["recall"].get<double>(), 0.0);
  EXPECT_DOUBLE_EQ(half["all"]["precision"].get<double>(), 1.0);
  // One camera on the line through both centres, beyond b: a's side facing it is behind b, except
  // a thin ring; b's facing half is seen. a keeps far fewer samples than b.
  const auto line = torch::tensor({10.0, 0.0, 0.0}, torch::kDouble).reshape({1, 3});
  const auto [seen, who] = visible_sphere_samples(spheres, line, 4000);
  const int64_t a_seen = (who == 0).sum().item<int64_t>(), b_seen = (who == 1).sum().item<int64_t>();
  EXPECT_NEAR(static_cast<double>(b_seen) / 4000, 0.5 * (1 - 0.5 / 7.0), 0.02);  // the cap seen from 7 units
  EXPECT_LT(a_seen, b_seen / 4);
}

// Reference points (a COLMAP capture's) against exported geometry: a plane's grid of points at
// spacing 0.01; reference points over grid nodes at known heights have exactly those distances;
// points beyond the plane's box grown by 5% of its diagonal are not asked for.
TEST(SurfaceScore, ReferencePointsDistancesToThePlane) {
  const auto ticks = torch::arange(-100, 101, torch::kDouble) * 0.01;  // [-1, 1] in steps of 0.01
  const auto grid = torch::meshgrid({ticks, ticks}, "ij");
  const auto plane =
      torch::stack({grid[0].reshape(-1), grid[1].reshape(-1), torch::zeros({201 * 201}, torch::kDouble)}, 1);
  // Over nodes: heights 0, 0.01, -0.03, 0.1; beyond the grown box (pad 0.05 * 2.83 = 0.141): z = 0.2 and x = 1.5.
  const auto ref =
      torch::tensor({0.0, 0.0, 0.0, 0.5, -0.25, 0.01, -0.7, 0.3, -0.03, 0.2, 0.9, 0.1, 0.0, 0.0, 0.2, 1.5, 0.0, 0.0},
                    torch::kDouble)
          .reshape({6, 3});
  const auto j = score_reference_points(plane, ref, 0.02);
  EXPECT_EQ(j["reference_points"].get<int64_t>(), 6);
  EXPECT_EQ(j["inside"].get<int64_t>(), 4);
  EXPECT_NEAR(j["distance_mean"].get<double>(), (0.0 + 0.01 + 0.03 + 0.1) / 4, 1e-12);
  EXPECT_NEAR(j["distance_median"].get<double>(), 0.01, 1e-12);  // torch's median: the lower of the middle two
  EXPECT_DOUBLE_EQ(j["within_tau"].get<double>(), 0.5);
  // Nothing inside: null figures.
  const auto none = score_reference_points(plane, ref.slice(0, 4, 6), 0.02);
  EXPECT_EQ(none["inside"].get<int64_t>(), 0);
  EXPECT_TRUE(none["distance_median"].is_null());
  // The default threshold: 1% of the central box's diagonal (a far stray point does not count).
  auto pts = torch::cat({plane, torch::tensor({{1000.0, 1000.0, 1000.0}}, torch::kDouble)});
  EXPECT_NEAR(reference_tau(pts), 0.01 * std::sqrt(2.0) * 1.96, 0.01 * 0.05);
}

// A geometry's depth against true depth (score_depth_against_truth), by hand: of the truth's three
// surface pixels the geometry sees two (errors 0.1 and 0.5) and misses one (infinity); of its two
// background pixels it puts a surface at one. Truth points (depth_truth_points) sit at
// origin + depth x direction for the pixels that hit.
TEST(SurfaceScore, DepthAgainstTrueDepth) {
  const auto truth = torch::tensor({0.0, 2.0, 3.0, 4.0, 0.0}, torch::kDouble);
  const double inf = std::numeric_limits<double>::infinity();
  const auto depth = torch::tensor({inf, 2.1, inf, 3.5, 1.0}, torch::kDouble);
  const auto j = score_depth_against_truth(depth, truth);
  EXPECT_EQ(j["pixels"].get<int64_t>(), 5);
  EXPECT_EQ(j["surface_pixels"].get<int64_t>(), 3);
  EXPECT_DOUBLE_EQ(j["hit_share"].get<double>(), 2.0 / 3.0);
  EXPECT_DOUBLE_EQ(j["false_surface_share"].get<double>(), 0.5);
  EXPECT_NEAR(j["depth_mae"].get<double>(), 0.3, 1e-12);
  EXPECT_NEAR(j["depth_median"].get<double>(), 0.1, 1e-12);  // the lower middle of two
  const auto none = score_depth_against_truth(torch::full({3}, INFINITY, torch::kDouble), truth.slice(0, 1, 4));
  EXPECT_TRUE(none["depth_mae"].is_null());
  EXPECT_DOUBLE_EQ(none["hit_share"].get<double>(), 0.0);

  DepthTruth t;
  t.origins = torch::tensor({{0.f, 0.f, 4.f}, {1.f, 0.f, 4.f}});
  t.directions = torch::tensor({{0.f, 0.f, -1.f}, {0.5f, 0.f, -1.f}});
  t.depth = torch::tensor({2.f, 0.f});
  const auto pts = depth_truth_points(t);
  ASSERT_EQ(pts.size(0), 1);
  EXPECT_TRUE(torch::allclose(pts[0], torch::tensor({0.0, 0.0, 2.0}, torch::kDouble)));
}

// A mesh's depth map (fuse.h, mesh_depth_maps) against the closed form: the tilted plane
// z = 0.3 x (two triangles, 6 units across) seen from (0, 0, 4) looking down -z, off-centre
// principal point. The ray (xn, yn, -1) from the camera meets it at depth t = 4 / (1 + 0.3 xn): exact
// only if 1/z is interpolated across each triangle, not z. A point cloud has no depth map.
TEST(Geometry, MeshDepthMapOfATiltedPlaneIsTheRayIntersection) {
  test::TempDir t;
  auto z = [](double x) { return 0.3 * x; };
  std::ostringstream ply;
  ply << "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
         "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
      << "-3 -3 " << z(-3) << "\n3 -3 " << z(3) << "\n3 3 " << z(3) << "\n-3 3 " << z(-3) << "\n3 0 1 2\n3 0 2 3\n";
  test::write_file(t / "tilted.ply", ply.str());
  const Intrinsics k = test::pinhole(24, 18, 30, 28, 11, 10);
  const auto c2w = torch::tensor({{1.f, 0.f, 0.f, 0.f}, {0.f, 1.f, 0.f, 0.f}, {0.f, 0.f, 1.f, 4.f}});
  const auto maps = mesh_depth_maps(t / "tilted.ply", {{c2w, k}});
  ASSERT_EQ(maps.size(), 1u);
  ASSERT_EQ(maps[0].sizes(), (std::vector<int64_t>{18, 24}));
  for (int r = 0; r < k.height; ++r)
    for (int c = 0; c < k.width; ++c) {
      const double xn = (c + 0.5 - k.cx) / k.fx;
      EXPECT_NEAR(maps[0][r][c].item<double>(), 4.0 / (1.0 + 0.3 * xn), 1e-4) << r << "," << c;
    }
  // The camera moved 3 units sideways sees the square's edge: no surface beyond it.
  const auto aside = torch::tensor({{1.f, 0.f, 0.f, 3.f}, {0.f, 1.f, 0.f, 0.f}, {0.f, 0.f, 1.f, 4.f}});
  const auto edge = mesh_depth_maps(t / "tilted.ply", {{aside, k}})[0];
  EXPECT_TRUE(std::isinf(edge[9][23].item<float>()));
  EXPECT_TRUE(std::isfinite(edge[9][0].item<float>()));
  test::write_file(t / "points.ply",
                   "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                   "property float z\nend_header\n0 0 0\n");
  EXPECT_TRUE(mesh_depth_maps(t / "points.ply", {{c2w, k}}).empty());
}

// The picture of points and cameras (geometry/preview.h): the view's axes are a right-handed
// orthonormal frame; a cube's eight corners seen along -x put the four nearer ones (x = +1) at the
// picture's four extreme pixels, computed by hand; a camera at (3,0,0) looking down -x is drawn
// from the centre pixel; from straight above, the upper corners win.
TEST(GeometryPreview, NearestPointsInFrontAndCamerasDrawn) {
  for (const auto& [az, el] : std::vector<std::pair<double, double>>{{0, 0}, {45, 35}, {200, -20}, {0, 90}}) {
    const auto a = preview_axes(az, el);
    EXPECT_LT((torch::matmul(a, a.t()) - torch::eye(3, torch::kDouble)).abs().max().item<double>(), 1e-12);
    EXPECT_LT((torch::cross(a[0], a[1], 0) - a[2]).abs().max().item<double>(),
              1e-12);  // right x up = towards the viewer
  }
  std::vector<double> xyz, rgb;
  for (int x : {-1, 1})
    for (int y : {-1, 1})
      for (int z : {-1, 1}) {
        xyz.insert(xyz.end(), {double(x), double(y), double(z)});
        rgb.insert(rgb.end(), {x > 0 ? 1.0 : 0.0, y > 0 ? 1.0 : 0.0, z > 0 ? 1.0 : 0.0});
      }
  const auto p = torch::tensor(xyz, torch::kDouble).reshape({8, 3});
  const auto c = torch::tensor(rgb, torch::kDouble).reshape({8, 3});
  // A camera at (3,0,0) looking down -x (OpenGL: its +z axis is world +x), image 20x20.
  const auto c2w =
      torch::tensor({0.0, 0.0, 1.0, 3.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0}, torch::kDouble).reshape({1, 3, 4});
  Intrinsics k;
  k.fx = k.fy = 20, k.cx = k.cy = 10, k.width = k.height = 20;
  PreviewOptions o;
  o.width = o.height = 101;
  o.azimuth_deg = 0, o.elevation_deg = 0;  // screen right = +y, up = +z, towards the viewer = +x
  const auto img = draw_preview(p, c, c2w, k, o);
  ASSERT_EQ(img.sizes(), (std::vector<int64_t>{101, 101, 3}));
  // Extent [-1,1] on both screen axes, scale 0.9 * 101 / 2; +-1 lands on pixel 95 or 5.
  const auto px = [&](int row, int col) { return img[row][col]; };
  for (const auto& [row, col, y, z] :
       std::vector<std::tuple<int, int, int, int>>{{5, 95, 1, 1}, {5, 5, -1, 1}, {95, 95, 1, -1}, {95, 5, -1, -1}}) {
    const auto v = px(row, col);
    EXPECT_EQ(v[0].item<float>(), 1.0f) << row << "," << col;  // the x = +1 corner, nearer the viewer
    EXPECT_EQ(v[1].item<float>(), y > 0 ? 1.0f : 0.0f);
    EXPECT_EQ(v[2].item<float>(), z > 0 ? 1.0f : 0.0f);
  }
  // The camera's centre is on the view's axis: the middle pixel is the cameras' colour.
  EXPECT_NEAR(px(50, 50)[0].item<float>(), 1.0f, 1e-6);
  EXPECT_NEAR(px(50, 50)[1].item<float>(), 0.62f, 1e-6);
  // Background elsewhere, e.g. between the corners on the top row, away from the camera's pyramid.
  EXPECT_NEAR(px(5, 30)[0].item<float>(), 0.12f, 1e-6);
  // From straight above (+z towards the viewer; +x right, +y up on the screen) the z = +1 corners win.
  o.elevation_deg = 90;
  const auto top = draw_preview(p, c, torch::zeros({0, 3, 4}, torch::kDouble), k, o);
  EXPECT_EQ(top[5][95][2].item<float>(), 1.0f);
  EXPECT_EQ(top[5][95][0].item<float>(), 1.0f);  // x = +1 is right
  EXPECT_EQ(top[5][95][1].item<float>(), 1.0f);  // y = +1 is up
}

}  // namespace
}  // namespace ablenerf
