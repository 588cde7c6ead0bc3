#include "geometry/surface_score.h"

#include <cmath>
#include <vector>

#include "data/depth_file.h"
#include "data/rays.h"
#include "geometry/depth_points.h"
#include "geometry/fuse.h"
#include "util/errors.h"

namespace ablenerf {

namespace {

// A sphere's centre as a (3) float64 tensor.
torch::Tensor centre_of(const synth::SphereTruth& s) {
  return torch::tensor({s.centre[0], s.centre[1], s.centre[2]}, torch::kDouble);
}

// Distance from each row of p (N,3) to the surface of every sphere: (N, S).
torch::Tensor surface_distances(const torch::Tensor& p, const std::vector<synth::SphereTruth>& spheres) {
  std::vector<torch::Tensor> cols;
  for (const auto& s : spheres) cols.push_back(((p - centre_of(s)).norm(2, -1) - s.radius).abs());
  return torch::stack(cols, 1);
}

nlohmann::json summary(const torch::Tensor& acc, const torch::Tensor& comp, double tau) {
  nlohmann::json j;
  const int64_t n = acc.size(0), k = comp.size(0);
  j["points"] = n;
  j["samples"] = k;
  const double am = n ? acc.mean().item<double>() : NAN, cm = k ? comp.mean().item<double>() : NAN;
  const double precision = n ? (acc < tau).to(torch::kDouble).mean().item<double>() : 0.0;
  const double recall = k ? (comp < tau).to(torch::kDouble).mean().item<double>() : 0.0;
  j["accuracy_mean"] = std::isfinite(am) ? nlohmann::json(am) : nlohmann::json(nullptr);
  j["completeness_mean"] = std::isfinite(cm) ? nlohmann::json(cm) : nlohmann::json(nullptr);
  j["chamfer"] = std::isfinite(am) && std::isfinite(cm) ? nlohmann::json(0.5 * (am + cm)) : nlohmann::json(nullptr);
  j["precision"] = precision;
  j["recall"] = recall;
  j["fscore"] = precision + recall > 0 ? 2 * precision * recall / (precision + recall) : 0.0;
  return j;
}

}  // namespace

std::pair<torch::Tensor, torch::Tensor> visible_sphere_samples(const std::vector<synth::SphereTruth>& spheres,
                                                               const torch::Tensor& eyes, int64_t per_sphere) {
  const auto i = torch::arange(per_sphere, torch::kDouble);
  const auto z = 1 - (2 * i + 1) / static_cast<double>(per_sphere);
  const auto r = torch::sqrt(1 - z * z), phi = i * 2.399963229728653;                // the golden angle
  const auto unit = torch::stack({r * torch::cos(phi), r * torch::sin(phi), z}, 1);  // (P,3)
  const auto e = eyes.to(torch::kDouble);
  std::vector<torch::Tensor> centres;
  for (const auto& s : spheres) centres.push_back(centre_of(s));
  std::vector<torch::Tensor> kept, owner;
  for (size_t s = 0; s < spheres.size(); ++s) {
    const auto p = centres[s] + unit * spheres[s].radius;  // (P,3)
    auto seen = torch::zeros({per_sphere}, torch::kBool);
    for (int64_t m = 0; m < e.size(0); ++m) {
      const auto to_eye = e[m] - p;                // (P,3)
      auto visible = (to_eye * unit).sum(-1) > 0;  // facing the camera
      const auto len = to_eye.norm(2, -1, true);
      const auto d = to_eye / len;
      for (size_t o = 0; o < spheres.size(); ++o) {
        if (o == s) continue;
        // Does the segment p -> eye pass through sphere o?
        const auto oc = p - centres[o];
        const auto b = (oc * d).sum(-1), cc = (oc * oc).sum(-1) - spheres[o].radius * spheres[o].radius;
        const auto disc = b * b - cc;
        const auto t = -b - torch::sqrt(disc.clamp_min(0));
        visible = visible & ~((disc > 0) & (t > 0) & (t < len.squeeze(-1)));
      }
      seen = seen | visible;
    }
    const auto idx = seen.nonzero().squeeze(-1);
    kept.push_back(p.index_select(0, idx));
    owner.push_back(torch::full({idx.size(0)}, static_cast<int64_t>(s), torch::kLong));
  }
  return {torch::cat(kept), torch::cat(owner)};
}

nlohmann::json score_against_spheres(const torch::Tensor& points, const std::vector<synth::SphereTruth>& spheres,
                                     const torch::Tensor& eyes, double tau, int64_t per_sphere) {
  const auto p = points.to(torch::kDouble).reshape({-1, 3});
  const auto [samples, owner] = visible_sphere_samples(spheres, eyes, per_sphere);
  const auto dist = surface_distances(p, spheres);
  const auto [acc, nearest] = dist.min(1);
  const auto comp = nearest_distances(samples, p);
  nlohmann::json out;
  out["tau"] = tau;
  out["all"] = summary(acc, comp, tau);
  for (size_t s = 0; s < spheres.size(); ++s) {
    const auto mine = (nearest == static_cast<int64_t>(s)).nonzero().squeeze(-1);
    const auto own = (owner == static_cast<int64_t>(s)).nonzero().squeeze(-1);
    auto j = summary(acc.index_select(0, mine), comp.index_select(0, own), tau);
    j["material"] = spheres[s].material;
    out[spheres[s].name] = j;
  }
  return out;
}

nlohmann::json score_reference_points(const torch::Tensor& geometry, const torch::Tensor& reference, double tau) {
  const auto g = geometry.to(torch::kDouble).reshape({-1, 3});
  const auto r = reference.to(torch::kDouble).reshape({-1, 3});
  nlohmann::json j;
  j["reference_points"] = r.size(0);
  j["tau"] = tau;
  torch::Tensor inside = r.slice(0, 0, 0);
  if (g.size(0) > 0 && r.size(0) > 0) {
    const auto lo = std::get<0>(g.min(0)), hi = std::get<0>(g.max(0));
    const auto pad = 0.05 * (hi - lo).norm();
    const auto keep = ((r >= lo - pad) & (r <= hi + pad)).all(1);
    inside = r.index_select(0, keep.nonzero().squeeze(-1));
  }
  j["inside"] = inside.size(0);
  if (inside.size(0) == 0) {
    j["distance_median"] = j["distance_mean"] = j["within_tau"] = nullptr;
    return j;
  }
  const auto d = nearest_distances(inside, g);
  j["distance_median"] = d.median().item<double>();
  j["distance_mean"] = d.mean().item<double>();
  j["within_tau"] = (d < tau).to(torch::kDouble).mean().item<double>();
  return j;
}

DepthTruth depth_truth(const CaptureSplit& split, int64_t view_step, int64_t pixel_step) {
  DepthTruth truth;
  std::vector<torch::Tensor> origins, directions, depths;
  for (size_t i = 0; i < split.frames.size(); i += static_cast<size_t>(view_step)) {
    const CaptureFrame& fr = split.frames[i];
    if (fr.depth.empty()) continue;
    const auto depth = read_frame_depth(fr);
    const Intrinsics k = fr.camera.scaled(static_cast<double>(depth.size(1)) / fr.camera.width,
                                          static_cast<int>(depth.size(1)), static_cast<int>(depth.size(0)));
    const auto c2w = torch::tensor(std::vector<float>(fr.pose.begin(), fr.pose.end())).view({3, 4});
    const Rays rays = rays_for_image(c2w, k);
    auto keep = torch::zeros(depth.sizes(), torch::kBool);
    keep.index_put_({torch::indexing::Slice(0, torch::indexing::None, pixel_step),
                     torch::indexing::Slice(0, torch::indexing::None, pixel_step)},
                    true);
    const auto idx = keep.reshape({-1}).nonzero().squeeze(-1);
    truth.cameras.emplace_back(c2w, k);
    truth.pixels.push_back(idx);
    origins.push_back(rays.origins.index_select(0, idx));
    directions.push_back(rays.directions.index_select(0, idx));
    depths.push_back(depth.reshape({-1}).index_select(0, idx));
  }
  if (depths.empty()) {
    truth.origins = truth.directions = torch::empty({0, 3});
    truth.depth = torch::empty({0});
  } else {
    truth.origins = torch::cat(origins);
    truth.directions = torch::cat(directions);
    truth.depth = torch::cat(depths);
  }
  return truth;
}

torch::Tensor depth_truth_points(const DepthTruth& truth) {
  const auto hit = (truth.depth > 0).nonzero().squeeze(-1);
  return (truth.origins.index_select(0, hit) +
          truth.directions.index_select(0, hit) * truth.depth.index_select(0, hit).unsqueeze(-1))
      .to(torch::kDouble);
}

nlohmann::json score_depth_against_truth(const torch::Tensor& depth, const torch::Tensor& truth) {
  const auto d = depth.to(torch::kDouble).reshape({-1}), t = truth.to(torch::kDouble).reshape({-1});
  const auto surface = t > 0, seen = torch::isfinite(d) & (d > 0);
  const auto both = surface & seen;
  nlohmann::json j;
  j["pixels"] = t.size(0);
  j["surface_pixels"] = surface.sum().item<int64_t>();
  const int64_t n_surface = j["surface_pixels"].get<int64_t>(), n_both = both.sum().item<int64_t>();
  const int64_t n_background = t.size(0) - n_surface;
  j["hit_share"] = n_surface ? static_cast<double>(n_both) / n_surface : 0.0;
  j["false_surface_share"] =
      n_background ? (seen & ~surface).sum().item<double>() / static_cast<double>(n_background) : 0.0;
  if (n_both) {
    const auto err = (d - t).masked_select(both).abs();
    j["depth_mae"] = err.mean().item<double>();
    j["depth_median"] = err.median().item<double>();
  } else {
    j["depth_mae"] = j["depth_median"] = nullptr;
  }
  return j;
}

nlohmann::json score_against_truth_points(const torch::Tensor& geometry, const torch::Tensor& truth, double tau) {
  const auto g = geometry.to(torch::kDouble).reshape({-1, 3}), t = truth.to(torch::kDouble).reshape({-1, 3});
  nlohmann::json out = summary(nearest_distances(g, t), nearest_distances(t, g), tau);
  out["tau"] = tau;
  return out;
}

double reference_tau(const torch::Tensor& points) {
  const auto p = points.reshape({-1, 3});
  return p.size(0) == 0 ? 0.0 : 0.01 * CropBox::around(p, 0.98, 0.0).diagonal();
}

}  // namespace ablenerf
