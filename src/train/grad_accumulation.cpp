#include "train/grad_accumulation.h"

#include <vector>

#include "model/compute.h"
#include "model/cpu_parallel.h"

namespace ablenerf {

namespace {
// Fewest rays per CPU thread in a ray-parallel training slice.
constexpr int64_t kMinRaysPerWorker = 8;
constexpr double kChannels = 3.0;
}  // namespace

LossTerms ray_loss(const ModelOutput& out, const torch::Tensor& target, const TrainConfig& tc, int64_t global_rays) {
  const double inv = 1.0 / (kChannels * static_cast<double>(global_rays));
  const auto se_c = (out.rgb_coarse - target).pow(2).sum();
  const auto se_f = (out.rgb_fine - target).pow(2).sum();
  return {(tc.coarse_weight * se_c + tc.fine_weight * se_f) * inv, se_f.detach() * inv};
}

StepSums accumulate_gradients(AbleNerf& model, const RayBatch& batch, int64_t micro, const TrainConfig& tc,
                              int64_t global_rays, double near, double far) {
  TORCH_CHECK(micro > 0, "accumulate_gradients: micro-batch must be positive");
  const auto params = model->parameters();
  // Slices on threads only where no random stream is drawn (jitter would depend on the split).
  const bool split = params.front().device().is_cpu() && cpu_split() == CpuSplit::Rays && !model->config().randomized;
  StepSums sums;
  for (int64_t b = 0; b < batch.size(); b += micro) {
    const RayBatch mb = batch.slice(b, std::min(b + micro, batch.size()));
    const int64_t workers = split ? cpu_workers(mb.size(), kMinRaysPerWorker) : 1;
    if (workers == 1) {
      const LossTerms t = ray_loss(model->forward(mb.rays, near, far), mb.target, tc, global_rays);
      t.loss.backward();
      sums.loss += t.loss.item<double>();
      sums.mse_fine += t.mse_fine.item<double>();
      continue;
    }
    std::vector<std::vector<torch::Tensor>> grads(static_cast<size_t>(workers));
    std::vector<StepSums> parts(static_cast<size_t>(workers));
    parallel_slices(mb.size(), workers, [&](int64_t w, int64_t lo, int64_t hi) {
      const RayBatch s = mb.slice(lo, hi);
      const LossTerms t = ray_loss(model->forward(s.rays, near, far), s.target, tc, global_rays);
      // Gradients returned, not accumulated, so the threads never write the same .grad.
      grads[static_cast<size_t>(w)] = torch::autograd::grad({t.loss}, params, /*grad_outputs=*/{},
                                                            /*retain_graph=*/false, /*create_graph=*/false,
                                                            /*allow_unused=*/true);
      parts[static_cast<size_t>(w)] = {t.loss.item<double>(), t.mse_fine.item<double>()};
    });
    torch::NoGradGuard no_grad;
    for (size_t w = 0; w < grads.size(); ++w) {
      sums.loss += parts[w].loss;
      sums.mse_fine += parts[w].mse_fine;
      for (size_t i = 0; i < params.size(); ++i) {
        const auto& g = grads[w][i];
        if (!g.defined()) continue;
        auto& acc = params[i].mutable_grad();
        if (acc.defined()) {
          acc.add_(g);
        } else {
          acc = g.clone();
        }
      }
    }
  }
  return sums;
}

}  // namespace ablenerf
