#include "train/grad_accumulation.h"

#include <vector>

#include "kernels/cpu_parallel.h"
#include "train/regularisers.h"
#include "train/train_config.h"

namespace ablenerf {

LossTerms ray_loss(const ModelOutput& out, const torch::Tensor& target, const TrainConfig& tc, int64_t global_rays) {
  const double inv = 1.0 / (static_cast<double>(kRgbChannels) * static_cast<double>(global_rays));
  const auto se_c = (out.rgb_coarse - target).pow(2).sum();
  const auto ray_se = (out.rgb_fine - target).pow(2).sum(-1);
  const auto se_f = ray_se.sum();
  auto loss = (tc.coarse_weight * se_c + tc.fine_weight * se_f) * inv;
  if (tc.distortion_weight > 0)
    loss = loss + distortion_loss(attention_distribution(out.fine_weights), out.fine_s).sum() *
                      (tc.distortion_weight / static_cast<double>(global_rays));
  if (tc.proposal_weight > 0 && out.proposal_weights.defined())
    loss = loss + proposal_loss(out.proposal_s, out.proposal_weights, out.fine_s,
                                attention_distribution(out.fine_weights).detach())
                          .sum() *
                      (tc.proposal_weight / static_cast<double>(global_rays));
  return {loss, se_f.detach() * inv, ray_se.detach()};
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

}  // namespace

StepSums accumulate_gradients(AbleNerf& model, const RayBatch& batch, int64_t micro, const TrainConfig& tc,
                              int64_t global_rays, double near, double far) {
  TORCH_CHECK(micro > 0, "accumulate_gradients: micro-batch must be positive");
  const auto params = model->parameters();
  // In the parameters' dtype (fp32 in training; float64 in tests).
  const auto zero = torch::zeros({}, params.front().options());
  StepSums sums{zero, zero.clone(), {}};
  std::vector<torch::Tensor> ray_se;
  const auto add = [&](const LossTerms& t) {
    sums.loss.add_(t.loss.detach());
    sums.mse_fine.add_(t.mse_fine);
    ray_se.push_back(t.ray_se);
  };
  for (int64_t b = 0; b < batch.size(); b += micro) {
    const RayBatch mb = batch.slice(b, std::min(b + micro, batch.size()));
    // The micro-batch's stratified jitter (model.randomized) is drawn here, on this thread and
    // before the split, so that a step does not depend on how many threads share it.
    ForwardOptions opts = model->with_jitter(mb.size(), {});
    opts.weights_grad = tc.distortion_weight > 0;
    const int64_t workers = model->cpu_ray_workers(mb.size(), /*draws_randomness=*/false);
    if (workers == 1) {
      const LossTerms t = ray_loss(through_photo_colour(model, model->forward(mb.rays, near, far, opts), mb.photo),
                                   mb.target, tc, global_rays);
      t.loss.backward();
      add(t);
      continue;
    }
    std::vector<std::vector<torch::Tensor>> grads(static_cast<size_t>(workers));
    std::vector<LossTerms> parts(static_cast<size_t>(workers));
    parallel_slices(mb.size(), workers, [&](int64_t w, int64_t lo, int64_t hi) {
      const RayBatch s = mb.slice(lo, hi);
      LossTerms t =
          ray_loss(through_photo_colour(model, model->forward(s.rays, near, far, opts.slice(lo, hi)), s.photo),
                   s.target, tc, global_rays);
      // Gradients returned, not accumulated, so the threads never write the same .grad.
      grads[static_cast<size_t>(w)] = torch::autograd::grad({t.loss}, params, /*grad_outputs=*/{},
                                                            /*retain_graph=*/false, /*create_graph=*/false,
                                                            /*allow_unused=*/true);
      parts[static_cast<size_t>(w)] = {t.loss.detach(), t.mse_fine, t.ray_se};
    });
    torch::NoGradGuard no_grad;
    for (size_t w = 0; w < grads.size(); ++w) add(parts[w]);
    // In slice order. A parameter's first sum is a new tensor (g0 + g1 + ...): the gradients
    // autograd returns may share memory between parameters (an addition hands both operands the
    // same tensor), so none of them becomes a .grad that a later add_ would write through.
    for (size_t i = 0; i < params.size(); ++i) {
      auto& acc = params[i].mutable_grad();
      for (size_t w = 0; w < grads.size(); ++w) {
        const auto& g = grads[w][i];
        if (!g.defined()) continue;
        if (acc.defined()) {
          acc.add_(g);
          continue;
        }
        // The first two defined slices in one op when there are two; a lone one is copied.
        size_t next = w + 1;
        while (next < grads.size() && !grads[next][i].defined()) ++next;
        if (next < grads.size()) {
          acc = g + grads[next][i];
          w = next;
        } else {
          acc = g.clone(torch::MemoryFormat::Contiguous);
        }
      }
    }
  }
  // The table's decay once per step, this process's share of it (ranks add their gradients).
  if (tc.grid_decay > 0 && model->grid()) {
    const double share = static_cast<double>(batch.size()) / static_cast<double>(global_rays);
    const auto& grid = model->grid();
    const auto decay = add_grid_weight_decay(grid->table_parameter(), grid->lr_scale(), tc.grid_decay * share);
    sums.loss.add_(decay.to(sums.loss.dtype()));
  }
  // The photo colour maps' decay once per step, likewise: photo_colour_decay x the mean over photos
  // of the squared deviation from the identity, its gradient added directly.
  if (tc.photo_colour_decay > 0 && model->photo_colour()) {
    const double share = static_cast<double>(batch.size()) / static_cast<double>(global_rays);
    const torch::Tensor& d = model->photo_colour()->delta();
    torch::NoGradGuard no_grad;
    const double coeff = tc.photo_colour_decay * share / static_cast<double>(d.size(0));
    sums.loss.add_((d.pow(2).sum() * coeff).to(sums.loss.dtype()));
    auto& grad = d.mutable_grad();
    if (grad.defined())
      grad.add_(d, 2 * coeff);
    else
      grad = d * (2 * coeff);
  }
  sums.ray_se = ray_se.empty() ? torch::zeros({0}, zero.options()) : torch::cat(ray_se);
  return sums;
}

}  // namespace ablenerf
