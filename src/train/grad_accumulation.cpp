#include "train/grad_accumulation.h"

#include <algorithm>
#include <vector>

#include "kernels/attention_losses_cpu.h"
#include "kernels/cpu_parallel.h"
#include "kernels/table_gradient.h"
#include "train/regularisers.h"
#include "train/train_config.h"

namespace ablenerf {

LossTerms ray_loss(const ModelOutput& out, const torch::Tensor& target, const TrainConfig& tc, int64_t global_rays,
                   const torch::Tensor& distortion_scale, bool fused) {
  const double inv = 1.0 / (static_cast<double>(kRgbChannels) * static_cast<double>(global_rays));
  const auto ray_se = (out.rgb_fine - target).pow(2).sum(-1);
  const auto se_f = ray_se.sum();
  std::array<torch::Tensor, kLossTermCount> parts;
  parts[kTermFine] = se_f * (tc.fine_weight * inv);
  auto loss = parts[kTermFine];
  // Without a weight the coarse colour is not computed (accumulate_gradients).
  if (tc.coarse_weight > 0) {
    parts[kTermCoarse] = (out.rgb_coarse - target).pow(2).sum() * (tc.coarse_weight * inv);
    loss = parts[kTermCoarse] + loss;
  }
  const bool distortion = tc.distortion_weight > 0;
  const bool proposal = (tc.proposal_weight > 0 || tc.proposal_attention_weight > 0) && out.proposal_weights.defined();
  const double per_ray = 1.0 / static_cast<double>(global_rays);
  AttentionLosses a;
  if (fused && (distortion || proposal) &&
      attention_losses_cpu_available(out.fine_weights, out.fine_s, out.proposal_s, out.proposal_weights)) {
    a = attention_losses_cpu(out.fine_weights, out.fine_s, out.proposal_s, out.proposal_weights, proposal, distortion);
  } else {
    // The plain reference (train/regularisers.h), term by term.
    if (distortion) a.distortion = distortion_loss(attention_distribution(out.fine_weights), out.fine_s).sum();
    if (proposal && tc.proposal_weight > 0)
      a.proposal = proposal_loss(out.proposal_s, out.proposal_weights, out.fine_s,
                                 attention_distribution(out.fine_weights).detach())
                       .sum();
    if (proposal && tc.proposal_attention_weight > 0)
      a.attention = proposal_loss(out.proposal_s, out.proposal_weights.detach(), out.fine_s,
                                  attention_distribution(out.fine_weights))
                        .sum();
  }
  if (distortion) {
    parts[kTermDistortion] = a.distortion * (tc.distortion_weight * per_ray);
    if (distortion_scale.defined()) parts[kTermDistortion] = parts[kTermDistortion] * distortion_scale;
    loss = loss + parts[kTermDistortion];
  }
  if (proposal && tc.proposal_weight > 0) {
    parts[kTermProposal] = a.proposal * (tc.proposal_weight * per_ray);
    loss = loss + parts[kTermProposal];
  }
  if (proposal && tc.proposal_attention_weight > 0) {
    parts[kTermProposalAttention] = a.attention * (tc.proposal_attention_weight * per_ray);
    loss = loss + parts[kTermProposalAttention];
  }
  const auto zero = torch::zeros({}, se_f.options());
  std::vector<torch::Tensor> terms;
  for (const auto& t : parts) terms.push_back(t.defined() ? t.detach().reshape({}).to(zero.dtype()) : zero);
  return {loss, se_f.detach() * inv, ray_se.detach(), torch::stack(terms)};
}

namespace {

// The colours the loss compares, through the ray's photo's colour map (model/photo_colour.h) when
// the model has one.
ModelOutput through_photo_colour(AbleNerf& model, ModelOutput out, const torch::Tensor& photo) {
  PhotoColourImpl* pc = model->photo_colour();
  if (pc == nullptr || !photo.defined()) return out;
  out.rgb_fine = pc->forward(out.rgb_fine, photo);
  if (out.rgb_coarse.defined()) out.rgb_coarse = pc->forward(out.rgb_coarse, photo);
  return out;
}

// The rays as the photos' corrected cameras cast them (model/camera_refine.h) when the model refines
// its cameras.
Rays through_camera_refine(AbleNerf& model, const Rays& rays, const torch::Tensor& photo) {
  CameraRefineImpl* cr = model->camera_refine();
  if (cr == nullptr || !photo.defined()) return rays;
  return cr->forward(rays, photo);
}

// `opts` with each ray's photo's appearance code (model/appearance_code.h) when the model has codes.
ForwardOptions with_appearance(AbleNerf& model, ForwardOptions opts, const torch::Tensor& photo) {
  AppearanceCodeImpl* codes = model->appearance_code();
  if (codes != nullptr && photo.defined()) opts.appearance = codes->forward(photo);
  return opts;
}

// The loss terms of some rays of the step: through the corrected cameras, the model with the photos'
// appearance codes and the photo colour maps.
LossTerms slice_loss(AbleNerf& model, const RayBatch& rays, const ForwardOptions& opts, const TrainConfig& tc,
                     int64_t global_rays, double near, double far, const torch::Tensor& distortion_scale) {
  const ModelOutput out = model->forward(through_camera_refine(model, rays.rays, rays.photo), near, far,
                                         with_appearance(model, opts, rays.photo));
  return ray_loss(through_photo_colour(model, out, rays.photo), rays.target, tc, global_rays, distortion_scale,
                  model->compute().attention == AttentionKernel::Fused);
}

// Each parameter's gradients from the step's ray slices summed onto its .grad, in slice order. A
// parameter's first sum goes to a new tensor: the gradients autograd returns may share memory
// between parameters (an addition hands both operands the same tensor), so none of them becomes a
// .grad that a later add_ would write through. About 150 small sums a step: one ATen add each cost
// more in dispatch than in arithmetic, so contiguous ones of the parameter's dtype are summed by a
// plain loop, the parameters split between the threads by size; the rest through ATen.
void sum_slice_gradients(const std::vector<torch::Tensor>& params,
                         const std::vector<std::vector<torch::Tensor>>& grads) {
  struct Sum {
    torch::Tensor acc;
    std::vector<torch::Tensor> parts;  // the defined slices' gradients, in slice order
    bool onto;                         // acc held a gradient before this step's sum
  };
  std::vector<Sum> sums;
  std::vector<int64_t> ends;  // running element count, to split the loops by size
  int64_t total = 0;
  for (size_t i = 0; i < params.size(); ++i) {
    std::vector<torch::Tensor> parts;
    for (const auto& g : grads) {
      if (g[i].defined()) parts.push_back(g[i]);
    }
    if (parts.empty()) continue;
    auto& acc = params[i].mutable_grad();
    bool plain = true;
    for (const auto& g : parts)
      plain = plain && g.is_contiguous() && g.scalar_type() == params[i].scalar_type() && g.is_cpu() &&
              g.sizes() == params[i].sizes();
    const bool onto = acc.defined();
    if (onto) plain = plain && acc.is_contiguous() && acc.scalar_type() == params[i].scalar_type();
    if (!plain) {
      for (const auto& g : parts) acc = acc.defined() ? acc.add_(g) : g.clone(torch::MemoryFormat::Contiguous);
      continue;
    }
    if (!onto) acc = torch::empty_like(params[i], torch::MemoryFormat::Contiguous);
    total += acc.numel();
    sums.push_back({acc, std::move(parts), onto});
    ends.push_back(total);
  }
  if (sums.empty()) return;
  // Two halves by elements; a thread for each when there is enough to share.
  constexpr int64_t kMinElementsPerThread = 1 << 14;
  const int64_t workers = cpu_workers(total, kMinElementsPerThread);
  parallel_slices(total, workers, [&](int64_t, int64_t lo, int64_t hi) {
    // The parameters whose elements end inside [lo, hi) (each whole, to the thread its end falls to).
    size_t i = static_cast<size_t>(std::upper_bound(ends.begin(), ends.end(), lo) - ends.begin());
    for (; i < sums.size() && ends[i] <= hi; ++i) {
      Sum& s = sums[i];
      AT_DISPATCH_FLOATING_TYPES(s.acc.scalar_type(), "sum_slice_gradients", [&] {
        scalar_t* out = s.acc.data_ptr<scalar_t>();
        const int64_t n = s.acc.numel();
        size_t first = 0;
        if (!s.onto) {
          const scalar_t* a = s.parts[0].data_ptr<scalar_t>();
          if (s.parts.size() == 1) {
            std::copy_n(a, n, out);
          } else {
            const scalar_t* b = s.parts[1].data_ptr<scalar_t>();
            for (int64_t j = 0; j < n; ++j) out[j] = a[j] + b[j];
          }
          first = std::min<size_t>(2, s.parts.size());
        }
        for (size_t k = first; k < s.parts.size(); ++k) {
          const scalar_t* g = s.parts[k].data_ptr<scalar_t>();
          for (int64_t j = 0; j < n; ++j) out[j] += g[j];
        }
      });
    }
  });
}

}  // namespace

double near_gradient_distance_for(const TrainConfig& tc, double near) {
  return std::max(tc.near_gradient_distance, tc.near_gradient_near_multiple * near);
}

StepSums accumulate_gradients(AbleNerf& model, const RayBatch& batch, int64_t micro, const TrainConfig& tc,
                              int64_t global_rays, double near, double far, const torch::Tensor& distortion_scale,
                              bool tables_in_update) {
  TORCH_CHECK(micro > 0, "accumulate_gradients: micro-batch must be positive");
  const auto params = model->parameters();
  // In the parameters' dtype (fp32 in training; float64 in tests).
  const auto zero = torch::zeros({}, params.front().options());
  StepSums sums{zero, zero.clone(), {}, torch::zeros({kLossTermCount}, zero.options()), {}, {}};
  std::vector<torch::Tensor> ray_se;
  const auto add = [&](const LossTerms& t) {
    sums.loss.add_(t.loss.detach());
    sums.mse_fine.add_(t.mse_fine);
    sums.terms.add_(t.terms.to(sums.terms.dtype()));
    ray_se.push_back(t.ray_se);
  };
  // A decay's value, into the loss and its term.
  const auto add_decay = [&](LossTerm term, const torch::Tensor& value) {
    const auto v = value.to(sums.loss.dtype());
    sums.loss.add_(v);
    sums.terms[term].add_(v);
  };
  // The grid tables the step's threads write their gradients to (kernels/table_gradient.h).
  const auto tables = model->grids();
  try {
    for (int64_t b = 0; b < batch.size(); b += micro) {
      const RayBatch mb = batch.slice(b, std::min(b + micro, batch.size()));
      // The micro-batch's stratified jitter (model.randomized) is drawn here, on this thread and
      // before the split, so that a step does not depend on how many threads share it.
      ForwardOptions opts = model->with_jitter(mb.size(), {});
      // The coarse pass's colour only where its loss has a weight: without it the coarse pass
      // still places the fine samples and hands over its ray token, as when rendering.
      opts.coarse = tc.coarse_work();
      opts.weights_grad = tc.distortion_weight > 0 || tc.proposal_attention_weight > 0;
      opts.near_gradient_distance = near_gradient_distance_for(tc, near);
      const int64_t workers = model->cpu_ray_workers(mb.size(), /*draws_randomness=*/false);
      if (workers == 1) {
        const TableGradientScope key(0);
        const LossTerms t = slice_loss(model, mb, opts, tc, global_rays, near, far, distortion_scale);
        t.loss.backward();
        add(t);
        continue;
      }
      std::vector<std::vector<torch::Tensor>> grads(static_cast<size_t>(workers));
      std::vector<LossTerms> parts(static_cast<size_t>(workers));
      parallel_slices(mb.size(), workers, [&](int64_t w, int64_t lo, int64_t hi) {
        const TableGradientScope key(static_cast<int>(w));
        const RayBatch s = mb.slice(lo, hi);
        LossTerms t = slice_loss(model, s, opts.slice(lo, hi), tc, global_rays, near, far, distortion_scale);
        // Gradients returned, not accumulated, so the threads never write the same .grad.
        grads[static_cast<size_t>(w)] = torch::autograd::grad({t.loss}, params, /*grad_outputs=*/{},
                                                              /*retain_graph=*/false, /*create_graph=*/false,
                                                              /*allow_unused=*/true);
        parts[static_cast<size_t>(w)] = {t.loss.detach(), t.mse_fine, t.ray_se, t.terms};
      });
      torch::NoGradGuard no_grad;
      for (size_t w = 0; w < grads.size(); ++w) add(parts[w]);
      sum_slice_gradients(params, grads);
    }
  } catch (...) {
    for (auto* t : tables) t->table_gradient().discard();
    throw;
  }
  // The decays once per step, this process's share of them (ranks add their gradients): the grid
  // table's, in the pass that sums the tables' deferred lookups (on a GPU, where none is deferred,
  // on its own),
  const double share = static_cast<double>(batch.size()) / static_cast<double>(global_rays);
  for (auto* t : tables) {
    auto param = t->table_parameter();
    const bool front = t == model->grid();
    const double decay =
        front && tc.grid_decay > 0 ? grid_decay_coefficient(param, t->lr_scale(), tc.grid_decay * share) : 0.0;
    if (!param.is_cpu()) {
      if (decay > 0) add_decay(kTermGridDecay, add_grid_weight_decay(param, t->lr_scale(), tc.grid_decay * share));
      continue;
    }
    if (tables_in_update) {
      sums.tables.push_back({param, &t->table_gradient(), decay});
      continue;
    }
    const double value = t->table_gradient().finish(param, decay);
    if (t->table_gradient().wrote_finite_gradient()) sums.finite_tables.push_back(param);
    if (decay > 0) add_decay(kTermGridDecay, torch::scalar_tensor(value, zero.options()));
  }
  // and the photo colour maps', appearance codes' and camera corrections': each weight times the mean
  // over photos of the squared deviation from the identity.
  if (tc.photo_colour_decay > 0 && model->photo_colour()) {
    // On the maps' values, scale x the parameter (model/photo_colour.h).
    const PhotoColourImpl& pc = *model->photo_colour();
    const double weight = tc.photo_colour_decay * share * pc.lr_scale() * pc.lr_scale();
    add_decay(kTermPhotoColourDecay, add_row_decay(pc.parameter(), weight));
  }
  if (tc.appearance_code_decay > 0 && model->appearance_code()) {
    const double weight = tc.appearance_code_decay * share;
    add_decay(kTermAppearanceDecay, add_row_decay(model->appearance_code()->parameter(), weight));
  }
  if (tc.camera_refine_decay > 0 && model->camera_refine()) {
    // On the corrections, scale x the parameter (model/camera_refine.h).
    const CameraRefineImpl& cr = *model->camera_refine();
    const double weight = tc.camera_refine_decay * share * cr.lr_scale() * cr.lr_scale();
    add_decay(kTermCameraRefineDecay, add_row_decay(cr.parameter(), weight));
  }
  sums.ray_se = ray_se.empty() ? torch::zeros({0}, zero.options()) : torch::cat(ray_se);
  return sums;
}

}  // namespace ablenerf
