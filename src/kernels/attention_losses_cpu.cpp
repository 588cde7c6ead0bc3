#include "kernels/attention_losses_cpu.h"

#include <algorithm>
#include <vector>

namespace ablenerf {

namespace {

constexpr const char* kLossesOp = "attention_losses_cpu";
// attention_distribution's floor on a ray's attention sum, and mip-NeRF 360's epsilon in the
// proposal loss's denominator (train/regularisers.cpp).
constexpr double kSumFloor = 1e-6;
constexpr double kProposalEps = 1e-7;

// One ray's inputs: attention w (m), its fence-posts st (m + 1), the proposal's posts sp (n + 1)
// and weights wp (n; null without the proposal).
template <typename T>
struct Ray {
  const T* w;
  const T* st;
  const T* sp;
  const T* wp;
  int64_t m, n;
};

// What the forward and the backward both need of a ray, in float64; one kept for a whole loop over
// rays so that its vectors are allocated once.
struct RayState {
  double sum = 0;         // sum of w
  std::vector<double> a;  // w / max(sum, floor)
  // Proposal: c_k the proposal's weight before post k; per target interval j the proposal
  // intervals [lo_j, hi_j) that overlap it and the excess r_j = max(0, a_j - bound_j) over their
  // weight bound_j = c_hi - c_lo.
  std::vector<double> c;
  std::vector<int64_t> lo, hi;
  std::vector<double> r;
};

// Number of posts p[0..count) that are <= v (searchsorted with right = true).
template <typename T>
int64_t posts_at_or_below(const T* p, int64_t count, T v) {
  return std::upper_bound(p, p + count, v) - p;
}

template <typename T>
void fill_state(const Ray<T>& ray, bool proposal, RayState& st) {
  const int64_t m = ray.m, n = ray.n;
  st.sum = 0;
  for (int64_t j = 0; j < m; ++j) st.sum += static_cast<double>(ray.w[j]);
  const double denom = std::max(st.sum, kSumFloor);
  st.a.resize(static_cast<size_t>(m));
  for (int64_t j = 0; j < m; ++j) st.a[static_cast<size_t>(j)] = static_cast<double>(ray.w[j]) / denom;
  if (!proposal) return;
  auto& c = st.c;
  c.assign(static_cast<size_t>(n + 1), 0.0);
  for (int64_t k = 0; k < n; ++k) c[static_cast<size_t>(k + 1)] = c[static_cast<size_t>(k)] + ray.wp[k];
  st.lo.resize(static_cast<size_t>(m));
  st.hi.resize(static_cast<size_t>(m));
  st.r.resize(static_cast<size_t>(m));
  int64_t above = posts_at_or_below(ray.sp, n + 1, ray.st[0]);
  for (int64_t j = 0; j < m; ++j) {
    const int64_t above_next = posts_at_or_below(ray.sp, n + 1, ray.st[j + 1]);
    const int64_t lo = std::clamp<int64_t>(above - 1, 0, n), hi = std::clamp<int64_t>(above_next, 0, n);
    const auto u = static_cast<size_t>(j);
    st.lo[u] = lo;
    st.hi[u] = hi;
    st.r[u] = std::max(0.0, st.a[u] - (c[static_cast<size_t>(hi)] - c[static_cast<size_t>(lo)]));
    above = above_next;
  }
}

// sum_j r_j^2 / (a_j + eps).
double proposal_value(const RayState& st) {
  double v = 0;
  for (size_t j = 0; j < st.r.size(); ++j) v += st.r[j] * st.r[j] / (st.a[j] + kProposalEps);
  return v;
}

// mip-NeRF 360's distortion of the distribution a over the intervals of st.
template <typename T>
double distortion_value(const Ray<T>& ray, const RayState& st) {
  double before_w = 0, before_wm = 0, inter = 0, intra = 0;
  for (int64_t j = 0; j < ray.m; ++j) {
    const double a = st.a[static_cast<size_t>(j)], lo = ray.st[j], hi = ray.st[j + 1], mid = 0.5 * (lo + hi);
    inter += a * (mid * before_w - before_wm);
    intra += a * a * (hi - lo);
    before_w += a;
    before_wm += a * mid;
  }
  return 2 * inter + intra / 3;
}

// The batch's inputs as pointers, ray by ray (the proposal's null without it).
template <typename T>
struct Rays {
  const T *w, *st, *sp, *wp;
  int64_t count, m, n;

  Rays(const torch::Tensor& w_, const torch::Tensor& st_, const torch::Tensor& sp_, const torch::Tensor& wp_,
       bool proposal)
      : w(w_.data_ptr<T>()),
        st(st_.data_ptr<T>()),
        sp(proposal ? sp_.data_ptr<T>() : nullptr),
        wp(proposal ? wp_.data_ptr<T>() : nullptr),
        count(w_.size(0)),
        m(w_.size(1)),
        n(proposal ? wp_.size(1) : 0) {}

  Ray<T> at(int64_t b) const {
    return {w + b * m, st + b * (m + 1), sp ? sp + b * (n + 1) : nullptr, wp ? wp + b * n : nullptr, m, n};
  }
};

struct Sums {
  double proposal = 0, distortion = 0;
};

template <typename T>
Sums forward_rays(const torch::Tensor& w, const torch::Tensor& st, const torch::Tensor& sp, const torch::Tensor& wp,
                  bool proposal, bool distortion) {
  const Rays<T> rays(w, st, sp, wp, proposal);
  Sums s;
  RayState state;
  for (int64_t b = 0; b < rays.count; ++b) {
    const Ray<T> ray = rays.at(b);
    fill_state(ray, proposal, state);
    if (proposal) s.proposal += proposal_value(state);
    if (distortion) s.distortion += distortion_value(ray, state);
  }
  return s;
}

// Gradients of g_proposal x proposal + g_attention x attention + g_distortion x distortion: into
// dw (when defined) and dwp (when defined).
template <typename T>
void backward_rays(const torch::Tensor& w, const torch::Tensor& st, const torch::Tensor& sp, const torch::Tensor& wp,
                   bool proposal, bool distortion, double g_proposal, double g_attention, double g_distortion,
                   torch::Tensor& dw, torch::Tensor& dwp) {
  const Rays<T> rays(w, st, sp, wp, proposal);
  const int64_t m = rays.m, n = rays.n;
  T* out_w = dw.defined() ? dw.data_ptr<T>() : nullptr;
  T* out_wp = dwp.defined() ? dwp.data_ptr<T>() : nullptr;
  RayState state;
  std::vector<double> ga(static_cast<size_t>(m)), diff(static_cast<size_t>(n + 1));
  for (int64_t b = 0; b < rays.count; ++b) {
    const Ray<T> ray = rays.at(b);
    fill_state(ray, proposal, state);
    std::fill(ga.begin(), ga.end(), 0.0);
    if (proposal) {
      std::fill(diff.begin(), diff.end(), 0.0);
      for (int64_t j = 0; j < m; ++j) {
        const auto u = static_cast<size_t>(j);
        const double r = state.r[u], d = state.a[u] + kProposalEps;
        if (r <= 0) continue;
        // d/d bound_j of r^2 / d is -2 r / d; bound_j sums the proposal's weights lo_j .. hi_j - 1.
        const double x = g_proposal * (-2 * r / d);
        diff[static_cast<size_t>(state.lo[u])] += x;
        diff[static_cast<size_t>(state.hi[u])] -= x;
        // d/d a_j of r^2 / (a_j + eps) with r = a_j - bound_j > 0.
        ga[u] += g_attention * (2 * r * d - r * r) / (d * d);
      }
      if (out_wp) {
        double run = 0;
        for (int64_t k = 0; k < n; ++k) {
          run += diff[static_cast<size_t>(k)];
          out_wp[b * n + k] = static_cast<T>(run);
        }
      }
    }
    if (distortion && g_distortion != 0) {
      // d/d a_k: 2 (m_k W_<k - (wm)_<k + (wm)_>k - m_k W_>k) + 2/3 a_k (s_k+1 - s_k).
      double total_w = 0, total_wm = 0;
      for (int64_t j = 0; j < m; ++j) {
        const double mid = 0.5 * (static_cast<double>(ray.st[j]) + ray.st[j + 1]);
        total_w += state.a[static_cast<size_t>(j)];
        total_wm += state.a[static_cast<size_t>(j)] * mid;
      }
      double before_w = 0, before_wm = 0;
      for (int64_t j = 0; j < m; ++j) {
        const auto u = static_cast<size_t>(j);
        const double a = state.a[u], lo = ray.st[j], hi = ray.st[j + 1], mid = 0.5 * (lo + hi);
        const double after_w = total_w - before_w - a, after_wm = total_wm - before_wm - a * mid;
        ga[u] +=
            g_distortion * (2 * (mid * before_w - before_wm + after_wm - mid * after_w) + 2.0 / 3.0 * a * (hi - lo));
        before_w += a;
        before_wm += a * mid;
      }
    }
    if (out_w) {
      // Through a = w / max(sum w, floor): the quotient's gradient while the sum is above the floor
      // (where the floor's clamp passes the gradient), a constant denominator below it.
      T* o = out_w + b * m;
      if (state.sum >= kSumFloor) {
        double dot = 0;
        for (int64_t j = 0; j < m; ++j) dot += ga[static_cast<size_t>(j)] * state.a[static_cast<size_t>(j)];
        for (int64_t j = 0; j < m; ++j) o[j] = static_cast<T>((ga[static_cast<size_t>(j)] - dot) / state.sum);
      } else {
        for (int64_t j = 0; j < m; ++j) o[j] = static_cast<T>(ga[static_cast<size_t>(j)] / kSumFloor);
      }
    }
  }
}

class AttentionLossesFunction : public torch::autograd::Function<AttentionLossesFunction> {
 public:
  static torch::autograd::variable_list forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& w,
                                                const torch::Tensor& st, const torch::Tensor& sp,
                                                const torch::Tensor& wp, bool proposal, bool distortion) {
    ctx->save_for_backward({w, st, sp, wp});
    ctx->saved_data["proposal"] = proposal;
    ctx->saved_data["distortion"] = distortion;
    Sums s;
    AT_DISPATCH_FLOATING_TYPES(w.scalar_type(), kLossesOp,
                               [&] { s = forward_rays<scalar_t>(w, st, sp, wp, proposal, distortion); });
    const auto scalar = [&](double v) { return torch::scalar_tensor(v, w.options()); };
    return {scalar(s.proposal), scalar(s.proposal), scalar(s.distortion)};
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const torch::Tensor &w = saved[0], &st = saved[1], &sp = saved[2], &wp = saved[3];
    const bool proposal = ctx->saved_data["proposal"].toBool(), distortion = ctx->saved_data["distortion"].toBool();
    const auto value = [](const torch::Tensor& g) { return g.defined() ? g.item<double>() : 0.0; };
    const double g_proposal = value(grads[0]), g_attention = value(grads[1]), g_distortion = value(grads[2]);
    torch::Tensor dw, dwp;
    if (ctx->needs_input_grad(0)) dw = torch::empty_like(w);
    if (proposal && ctx->needs_input_grad(3)) dwp = torch::empty_like(wp);
    if (dw.defined() || dwp.defined()) {
      AT_DISPATCH_FLOATING_TYPES(w.scalar_type(), kLossesOp, [&] {
        backward_rays<scalar_t>(w, st, sp, wp, proposal, distortion, g_proposal, g_attention, g_distortion, dw, dwp);
      });
    }
    return {dw, torch::Tensor(), torch::Tensor(), dwp, torch::Tensor(), torch::Tensor()};
  }
};

bool plain_input(const torch::Tensor& t, const torch::Tensor& like) {
  return t.defined() && t.is_cpu() && t.dim() == 2 && t.scalar_type() == like.scalar_type();
}

}  // namespace

bool attention_losses_cpu_available(const torch::Tensor& w, const torch::Tensor& s_t, const torch::Tensor& s_p,
                                    const torch::Tensor& w_p) {
  if (!w.defined() || !w.is_cpu() || (w.scalar_type() != torch::kFloat && w.scalar_type() != torch::kDouble))
    return false;
  if (!plain_input(w, w) || !plain_input(s_t, w) || s_t.requires_grad()) return false;
  if (w_p.defined() && (!plain_input(w_p, w) || !plain_input(s_p, w) || s_p.requires_grad())) return false;
  return true;
}

AttentionLosses attention_losses_cpu(const torch::Tensor& w, const torch::Tensor& s_t, const torch::Tensor& s_p,
                                     const torch::Tensor& w_p, bool proposal, bool distortion) {
  TORCH_CHECK(
      attention_losses_cpu_available(w, s_t, proposal ? s_p : torch::Tensor(), proposal ? w_p : torch::Tensor()),
      kLossesOp,
      ": w, s_t (and with the proposal s_p, w_p) must be 2-D CPU tensors of one dtype, float32 or float64, "
      "the fence-posts without a gradient");
  TORCH_CHECK(s_t.size(0) == w.size(0) && s_t.size(1) == w.size(1) + 1, kLossesOp, ": s_t must have shape (", w.size(0),
              ", ", w.size(1) + 1, "), got ", s_t.sizes());
  if (proposal) {
    TORCH_CHECK(w_p.size(0) == w.size(0), kLossesOp, ": w_p must have ", w.size(0), " rows, got ", w_p.sizes());
    TORCH_CHECK(s_p.size(0) == w.size(0) && s_p.size(1) == w_p.size(1) + 1, kLossesOp, ": s_p must have shape (",
                w.size(0), ", ", w_p.size(1) + 1, "), got ", s_p.sizes());
  }
  // Without the proposal its inputs are empty (an autograd Function takes no undefined tensor).
  const auto in = [&](const torch::Tensor& t) { return proposal ? t.contiguous() : torch::empty({0}, w.options()); };
  const auto out =
      AttentionLossesFunction::apply(w.contiguous(), s_t.contiguous(), in(s_p), in(w_p), proposal, distortion);
  AttentionLosses r;
  if (proposal) r.proposal = out[0], r.attention = out[1];
  if (distortion) r.distortion = out[2];
  return r;
}

}  // namespace ablenerf
