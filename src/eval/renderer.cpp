#include "eval/renderer.h"

#include <algorithm>
#include <optional>
#include <vector>

#include "model/frustum.h"

namespace ablenerf {
namespace {
// Keeps the mean depth finite for a ray whose volume attention underflows to zero everywhere.
constexpr double kMinAttentionMass = 1e-12;

// Where the normalised attention's cumulative sum reaches each of `shares` (each in (0, 1)),
// linearly inside the interval that crosses it: (B, shares.size()), from one cumulative sum.
torch::Tensor depths_at_attention_shares(const torch::Tensor& weights, const torch::Tensor& t,
                                         const std::vector<double>& shares) {
  TORCH_CHECK(weights.dim() == 2 && t.dim() == 2 && t.size(0) == weights.size(0) && t.size(1) == weights.size(1) + 1,
              "depth_at_attention_share: expected weights (B,S) and t (B,S+1), got ", weights.sizes(), " and ",
              t.sizes());
  for (const double share : shares)
    TORCH_CHECK(share > 0 && share < 1, "depth_at_attention_share: share must lie in (0, 1), got ", share);
  const auto w = weights.to(t.scalar_type());
  // The interval i whose cumulative share first reaches each level, then linearly inside it.
  const auto part = w / w.sum(1, /*keepdim=*/true).clamp_min(kMinAttentionMass);
  const auto cdf = part.cumsum(1).contiguous();  // (B,S)
  const auto level = torch::tensor(shares, cdf.options()).unsqueeze(0).expand({w.size(0), -1}).contiguous();
  const auto i = torch::searchsorted(cdf, level).clamp_max(w.size(1) - 1);  // (B,K)
  const auto before = cdf.gather(1, (i - 1).clamp_min(0)) * (i > 0);
  const auto own = part.gather(1, i);
  const auto frac = ((level - before) / own.clamp_min(kMinAttentionMass)).clamp(0.0, 1.0);
  const auto t0 = t.gather(1, i), t1 = t.gather(1, i + 1);
  return t0 + frac * (t1 - t0);
}

}  // namespace

AttentionDepth depth_from_attention(const torch::Tensor& weights, const torch::Tensor& t) {
  TORCH_CHECK(weights.dim() == 2 && t.dim() == 2 && t.size(0) == weights.size(0) && t.size(1) == weights.size(1) + 1,
              "depth_from_attention: expected weights (B,S) and t (B,S+1), got ", weights.sizes(), " and ", t.sizes());
  const auto mid = interval_middles(t);  // (B,S)
  const auto w = weights.to(mid.scalar_type());
  AttentionDepth d;
  d.mean = (w * mid).sum(1) / w.sum(1).clamp_min(kMinAttentionMass);
  d.argmax = mid.gather(1, w.argmax(1, /*keepdim=*/true)).squeeze(1);
  const auto shares = depths_at_attention_shares(weights, t, {kAttentionFrontShare, 0.5});
  d.front = shares.select(1, 0);
  d.median = shares.select(1, 1);
  return d;
}

torch::Tensor depth_at_attention_share(const torch::Tensor& weights, const torch::Tensor& t, double share) {
  return depths_at_attention_shares(weights, t, {share}).squeeze(1);
}

RenderResult render_image(AbleNerf& model, const torch::Tensor& c2w, const Intrinsics& k, double near, double far,
                          int64_t chunk, const ForwardOptions& opts, const torch::Device& device,
                          const RenderProgress& progress) {
  TORCH_CHECK(chunk > 0, "render_image: chunk must be positive");
  TORCH_CHECK(k.width > 0 && k.height > 0, "render_image: empty image ", k.width, "x", k.height);
  TORCH_CHECK(c2w.dim() == 2 && c2w.size(0) >= 3 && c2w.size(1) == 4, "render_image: c2w must be (3,4) or (4,4)");
  torch::NoGradGuard no_grad;
  const int64_t h = k.height, w = k.width, n = h * w;
  // Results gather on the rendering device and come to the host once, at the end: a copy per
  // chunk would make the host wait for every chunk before queueing the next.
  const auto f32 = torch::TensorOptions().dtype(torch::kFloat).device(device);
  RenderResult out;
  out.rgb = torch::empty({n, 3}, f32);
  out.depth_mean = torch::empty({n}, f32);
  out.depth_front = torch::empty({n}, f32);
  out.depth_median = torch::empty({n}, f32);
  out.depth_argmax = torch::empty({n}, f32);
  if (opts.branches) {
    out.ray_colour = torch::empty({n, 3}, f32);
    out.le_colour = torch::empty({n, 3}, f32);
  }
  const auto pose = c2w.slice(0, 0, 3).to(device, torch::kFloat).unsqueeze(0);  // (1,3,4)
  const auto long_opts = torch::TensorOptions().dtype(torch::kLong).device(device);
  for (int64_t begin = 0; begin < n; begin += chunk) {
    const int64_t end = std::min(n, begin + chunk);
    // Pixel indices of this chunk, row-major like rays_for_image.
    const auto idx = torch::arange(begin, end, long_opts);
    const Rays rays = rays_for_pixels(pose.expand({end - begin, 3, 4}), idx.remainder(w), idx.div(w, "floor"), k);
    ForwardOptions o = opts;
    o.coarse.colour = false;  // an image needs only the fine colour
    std::optional<torch::Generator> gen;
    if (opts.generator) {
      gen = opts.generator->clone();
      o.generator = &*gen;
    }
    const ModelOutput m = model->forward(rays, near, far, o);
    out.rgb.slice(0, begin, end).copy_(m.rgb_fine);
    const auto depth = depth_from_attention(m.fine_weights, m.fine_t);
    out.depth_mean.slice(0, begin, end).copy_(depth.mean);
    out.depth_argmax.slice(0, begin, end).copy_(depth.argmax);
    out.depth_front.slice(0, begin, end).copy_(depth.front);
    out.depth_median.slice(0, begin, end).copy_(depth.median);
    if (opts.branches) {
      out.ray_colour.slice(0, begin, end).copy_(m.ray_colour_fine);
      out.le_colour.slice(0, begin, end).copy_(m.le_colour_fine);
    }
    if (progress) progress(end, n);
  }
  out.rgb = out.rgb.view({h, w, 3}).cpu();
  out.depth_mean = out.depth_mean.view({h, w}).cpu();
  out.depth_argmax = out.depth_argmax.view({h, w}).cpu();
  out.depth_front = out.depth_front.view({h, w}).cpu();
  out.depth_median = out.depth_median.view({h, w}).cpu();
  if (opts.branches) {
    out.ray_colour = out.ray_colour.view({h, w, 3}).cpu();
    out.le_colour = out.le_colour.view({h, w, 3}).cpu();
  }
  return out;
}

}  // namespace ablenerf
