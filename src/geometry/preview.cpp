#include "geometry/preview.h"

#include <algorithm>
#include <cmath>

#include "data/rays.h"

namespace ablenerf {

namespace {

constexpr float kBackground = 0.12f;
constexpr float kCameraColour[3] = {1.0f, 0.62f, 0.1f};

// A line from (x0,y0) to (x1,y1) in pixels, one sample per pixel along its longer axis.
void draw_line(torch::TensorAccessor<float, 3> img, double x0, double y0, double x1, double y1) {
  const int h = static_cast<int>(img.size(0)), w = static_cast<int>(img.size(1));
  const int steps = static_cast<int>(std::ceil(std::max(std::abs(x1 - x0), std::abs(y1 - y0)))) + 1;
  for (int s = 0; s <= steps; ++s) {
    const double t = static_cast<double>(s) / steps;
    const long x = std::lround(x0 + t * (x1 - x0)), y = std::lround(y0 + t * (y1 - y0));
    if (x < 0 || y < 0 || x >= w || y >= h) continue;
    for (int c = 0; c < 3; ++c) img[y][x][c] = kCameraColour[c];
  }
}

}  // namespace

torch::Tensor preview_axes(double azimuth_deg, double elevation_deg) {
  const double a = azimuth_deg * M_PI / 180, e = elevation_deg * M_PI / 180;
  const double toward[3] = {std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e)};
  // right = forward x up_world with forward = -toward; screen up = toward x right.
  double right[3] = {-toward[1], toward[0], 0.0};
  const double rn = std::hypot(right[0], right[1]);
  if (rn < 1e-12)
    right[0] = 1, right[1] = 0;  // straight down or up: +x is right
  else
    right[0] /= rn, right[1] /= rn;
  const double up[3] = {toward[1] * right[2] - toward[2] * right[1], toward[2] * right[0] - toward[0] * right[2],
                        toward[0] * right[1] - toward[1] * right[0]};
  return torch::tensor({right[0], right[1], right[2], up[0], up[1], up[2], toward[0], toward[1], toward[2]},
                       torch::kDouble)
      .reshape({3, 3});
}

torch::Tensor draw_preview(const torch::Tensor& xyz, const torch::Tensor& rgb, const torch::Tensor& c2w,
                           const Intrinsics& k, const PreviewOptions& opts) {
  const auto axes = preview_axes(opts.azimuth_deg, opts.elevation_deg);
  const auto p = xyz.to(torch::kDouble).reshape({-1, 3});
  auto cams = c2w.to(torch::kDouble);
  if (cams.dim() == 2) cams = cams.unsqueeze(0);
  cams = cams.slice(1, 0, 3);                        // (M,3,4) of (M,3,4) or (M,4,4)
  const auto centres = cams.select(2, 3);            // (M,3)
  const auto ps = torch::matmul(p, axes.t());        // (N,3): right, up, towards the viewer
  const auto cs = torch::matmul(centres, axes.t());  // (M,3)
  // The extent: the points' central 98% per screen axis and every camera centre.
  double lo[2] = {1e300, 1e300}, hi[2] = {-1e300, -1e300};
  if (ps.size(0) > 0) {
    const auto q = torch::quantile(ps.slice(1, 0, 2), torch::tensor({0.01, 0.99}, torch::kDouble), 0);
    for (int i = 0; i < 2; ++i) lo[i] = q[0][i].item<double>(), hi[i] = q[1][i].item<double>();
  }
  for (int64_t m = 0; m < cs.size(0); ++m)
    for (int i = 0; i < 2; ++i)
      lo[i] = std::min(lo[i], cs[m][i].item<double>()), hi[i] = std::max(hi[i], cs[m][i].item<double>());
  if (!(hi[0] >= lo[0]) || !(hi[1] >= lo[1])) lo[0] = lo[1] = -1, hi[0] = hi[1] = 1;  // nothing to draw
  const double extent = std::max({hi[0] - lo[0], hi[1] - lo[1], 1e-9});
  const int w = opts.width, h = opts.height;
  const double scale =
      0.9 * std::min(w / std::max(hi[0] - lo[0], 1e-9 * extent), h / std::max(hi[1] - lo[1], 1e-9 * extent));
  const double mid[2] = {0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1])};
  const auto to_px = [&](double sx, double sy) {
    return std::pair<double, double>{0.5 * w + (sx - mid[0]) * scale, 0.5 * h - (sy - mid[1]) * scale};
  };

  auto img = torch::full({h, w, 3}, kBackground, torch::kFloat);
  auto depth = torch::full({h, w}, -1e300, torch::kDouble);
  auto ia = img.accessor<float, 3>();
  auto da = depth.accessor<double, 2>();
  const auto psa = ps.accessor<double, 2>();
  const auto col = rgb.to(torch::kFloat).reshape({-1, 3}).contiguous();
  const auto ca = col.accessor<float, 2>();
  for (int64_t i = 0; i < ps.size(0); ++i) {
    const auto [x, y] = to_px(psa[i][0], psa[i][1]);
    const long px = std::lround(x - 0.5), py = std::lround(y - 0.5);
    if (px < 0 || py < 0 || px >= w || py >= h || psa[i][2] <= da[py][px]) continue;
    da[py][px] = psa[i][2];
    for (int c = 0; c < 3; ++c) ia[py][px][c] = std::clamp(ca[i][c], 0.0f, 1.0f);
  }

  // Cameras: centre to the four image corners at a depth of opts.frustum of the extent.
  if (cams.size(0) > 0) {
    const auto cc =
        torch::tensor({0.0, static_cast<double>(k.width), static_cast<double>(k.width), 0.0}, torch::kDouble);
    const auto cr =
        torch::tensor({0.0, 0.0, static_cast<double>(k.height), static_cast<double>(k.height)}, torch::kDouble);
    // Corner pixels' edges, not centres: rays_for_pixels adds half a pixel.
    const auto col_idx = cc - 0.5, row_idx = cr - 0.5;
    for (int64_t m = 0; m < cams.size(0); ++m) {
      const Rays r = rays_for_pixels(cams[m].unsqueeze(0).expand({4, 3, 4}), col_idx, row_idx, k);
      // Directions have camera-frame z = -1, so the pyramid's depth along the optical axis is exact.
      const auto corners = r.origins.to(torch::kDouble) + r.directions.to(torch::kDouble) * (opts.frustum * extent);
      const auto cs_corners = torch::matmul(corners, axes.t());
      const auto [x0, y0] = to_px(cs[m][0].item<double>(), cs[m][1].item<double>());
      std::pair<double, double> q[4];
      for (int i = 0; i < 4; ++i) q[i] = to_px(cs_corners[i][0].item<double>(), cs_corners[i][1].item<double>());
      for (int i = 0; i < 4; ++i) {
        draw_line(ia, x0, y0, q[i].first, q[i].second);
        draw_line(ia, q[i].first, q[i].second, q[(i + 1) % 4].first, q[(i + 1) % 4].second);
      }
    }
  }
  return img;
}

}  // namespace ablenerf
