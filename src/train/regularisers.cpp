#include "train/regularisers.h"

#include <algorithm>

namespace ablenerf {

double distortion_ramp(double start, double fraction, double ramp) {
  if (start <= 0) return 1.0;
  if (ramp <= 0) return fraction >= start ? 1.0 : 0.0;
  return std::clamp((fraction - start) / ramp, 0.0, 1.0);
}

torch::Tensor distortion_loss(const torch::Tensor& weights, const torch::Tensor& s) {
  TORCH_CHECK(weights.dim() == 2 && s.dim() == 2 && s.size(0) == weights.size(0) && s.size(1) == weights.size(1) + 1,
              "distortion_loss: weights (B,S) and fence-posts (B,S+1) expected");
  const int64_t n = weights.size(1);
  const auto& w = weights;
  const auto lo = s.slice(1, 0, n), hi = s.slice(1, 1, n + 1);
  const auto mid = 0.5 * (lo + hi);
  // Exclusive prefix sums W_<i and (wm)_<i.
  const auto wm = w * mid;
  const auto w_before = torch::cumsum(w, 1) - w;
  const auto wm_before = torch::cumsum(wm, 1) - wm;
  const auto inter = 2 * (w * (mid * w_before - wm_before)).sum(1);
  const auto intra = (w * w * (hi - lo)).sum(1) / 3;
  return inter + intra;
}

torch::Tensor attention_distribution(const torch::Tensor& weights) {
  // The floor only guards a ray whose attention is all on the ray token.
  return weights / weights.sum(-1, /*keepdim=*/true).clamp_min(1e-6);
}

torch::Tensor proposal_loss(const torch::Tensor& s_p, const torch::Tensor& w_p, const torch::Tensor& s_t,
                            const torch::Tensor& w_t) {
  TORCH_CHECK(w_p.dim() == 2 && s_p.dim() == 2 && s_p.size(1) == w_p.size(1) + 1 && w_t.dim() == 2 && s_t.dim() == 2 &&
                  s_t.size(1) == w_t.size(1) + 1 && s_p.size(0) == s_t.size(0),
              "proposal_loss: weights (B,N), (B,M) and fence-posts (B,N+1), (B,M+1) expected");
  // mip-NeRF 360's epsilon in the denominator.
  constexpr double kEps = 1e-7;
  const int64_t n = w_p.size(1);
  // Inclusive prefix sums of the proposal with a leading 0: c_k = sum_j<k w_p_j, k = 0..N.
  const auto c = torch::cat({torch::zeros({w_p.size(0), 1}, w_p.options()), torch::cumsum(w_p, 1)}, 1);
  const auto posts = s_p.contiguous();
  const auto target = s_t.to(posts.dtype()).contiguous();
  // The proposal intervals that overlap [a, b] are j = lo(a) .. hi(b) - 1: lo(a) the last post <= a,
  // hi(b) the first post > b (clamped to the ends).
  const auto above = torch::searchsorted(posts, target, /*out_int32=*/false, /*right=*/true);
  const auto lo = torch::clamp(above - 1, 0, n), hi = torch::clamp(above, 0, n);
  const int64_t m = w_t.size(1);
  const auto bound = c.gather(1, hi.slice(1, 1, m + 1)) - c.gather(1, lo.slice(1, 0, m));
  return (torch::clamp_min(w_t - bound, 0).pow(2) / (w_t + kEps)).sum(1);
}

torch::Tensor grid_weight_decay(const torch::Tensor& table) {
  TORCH_CHECK(table.dim() == 3, "grid_weight_decay: table (levels, rows, features) expected");
  return table.pow(2).mean({1, 2}).sum();
}

namespace {

// coeff x sum(param^2), with 2 coeff param added into param's .grad.
torch::Tensor add_squared_norm(const torch::Tensor& param, double coeff) {
  torch::NoGradGuard no_grad;
  // The norm, not a product and a sum: one reduction with no temporary (and float32 under autocast).
  const auto value = torch::linalg_vector_norm(param, 2, c10::nullopt, false, c10::nullopt).square() * coeff;
  auto& grad = param.mutable_grad();
  if (grad.defined())
    grad.add_(param, 2 * coeff);
  else
    grad = param * (2 * coeff);
  return value;
}

}  // namespace

double grid_decay_coefficient(const torch::Tensor& param, double scale, double weight) {
  TORCH_CHECK(param.dim() == 3, "grid decay: table (levels, rows, features) expected");
  // Every level has rows * features entries, so the sum of level means is one sum over the table.
  return weight * scale * scale / static_cast<double>(param.size(1) * param.size(2));
}

torch::Tensor add_grid_weight_decay(const torch::Tensor& param, double scale, double weight) {
  return add_squared_norm(param, grid_decay_coefficient(param, scale, weight));
}

torch::Tensor add_row_decay(const torch::Tensor& param, double weight) {
  TORCH_CHECK(param.dim() >= 1 && param.size(0) > 0, "add_row_decay: at least one row expected");
  return add_squared_norm(param, weight / static_cast<double>(param.size(0)));
}

}  // namespace ablenerf
