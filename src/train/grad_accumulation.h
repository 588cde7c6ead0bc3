#pragma once
// Forward + backward of one training step, shared by the trainer and `ablenerf bench`.
//
// The step's rays run in micro-batches (bounded memory); on the CPU with compute.cpu_split =
// "rays" each micro-batch is further cut into slices that run side by side on CPU threads
// (kernels/cpu_parallel.h), each slice computing its own gradients, which are then added to the
// parameters' .grad in slice order. The sum is deterministic for a given thread count; with one
// thread (or cpu_split = "ops", or on a GPU) it is a plain loss.backward() per micro-batch.
// Nothing here synchronises with the device (the sums are returned as device tensors), so on a
// GPU the whole function can be captured in a CUDA graph.
#include <array>
#include <torch/torch.h>

#include "model/able_nerf.h"
#include "train/adam.h"
#include "train/ray_batch.h"
#include "train/train_config.h"

namespace ablenerf {

// The terms the step's loss is the sum of, each as it enters the loss (weight included), so that
// they add up to StepSums::loss; train log lines carry them under these names.
enum LossTerm : int64_t {
  kTermFine,               // fine_weight x the fine colour's MSE
  kTermCoarse,             // coarse_weight x the coarse colour's MSE
  kTermDistortion,         // distortion_weight x the attention weights' distortion loss
  kTermProposal,           // proposal_weight x the proposal's loss
  kTermProposalAttention,  // proposal_attention_weight x the same loss on the attention
  kTermGridDecay,          // the grid table's normalised weight decay
  kTermPhotoColourDecay,   // the photo colour maps' decay
  kTermAppearanceDecay,    // the appearance codes' decay
  kTermCameraRefineDecay,  // the camera corrections' decay
  kLossTermCount
};
inline constexpr std::array<const char*, kLossTermCount> kLossTermNames = {"fine",
                                                                           "coarse",
                                                                           "distortion",
                                                                           "proposal",
                                                                           "proposal_attention",
                                                                           "grid_decay",
                                                                           "photo_colour_decay",
                                                                           "appearance_decay",
                                                                           "camera_refine_decay"};

struct LossTerms {
  torch::Tensor loss;      // what is differentiated
  torch::Tensor mse_fine;  // this slice's share of the step's fine-colour MSE (for reporting)
  torch::Tensor ray_se;    // (B,) each ray's fine-colour squared error summed over channels, detached
  torch::Tensor terms;     // (kLossTermCount,) the loss's terms (LossTerm), detached
};

// The loss of some rays of a step of `global_rays` rays: (coarse_weight * SE_coarse + fine_weight *
// SE_fine) / (3 * global_rays), SE = summed squared error over rays and channels, so that
// micro-batches, threads and ranks add up to the weighted MSE of the whole global batch; plus
// distortion_weight times the rays' distortion loss (train/regularisers.h) over global_rays, times
// `distortion_scale` (a 0-d tensor on the rays' device: train.distortion_start's ramp, which the
// trainer writes before each step so that a captured CUDA graph reads it) when it is defined.
// With coarse_weight 0 the coarse term is left out and out.rgb_coarse may be undefined: the step
// (accumulate_gradients) then does not compute the coarse colour (CoarseWork::colour).
// With `fused` (compute.attention = "fused") the distortion and proposal terms run as one CPU node
// where it can take them (kernels/attention_losses_cpu.h), else as the plain LibTorch functions of
// train/regularisers.h.
LossTerms ray_loss(const ModelOutput& out, const torch::Tensor& target, const TrainConfig& tc, int64_t global_rays,
                   const torch::Tensor& distortion_scale = {}, bool fused = false);

struct StepSums {
  torch::Tensor
      loss;  // the step's loss (this process's share), 0-d, in the parameters' dtype and on their device, detached
  torch::Tensor mse_fine;  // the step's fine-colour MSE (this process's share), likewise
  torch::Tensor ray_se;    // (rays,) LossTerms::ray_se of this process's rays, in batch order
  torch::Tensor terms;     // (kLossTermCount,) the loss's terms (LossTerm) summed likewise; they add up to loss
  // The grid tables whose gradient the pass that gathered it found finite (Adam::step_host's
  // `checked`; valid until the gradients change, e.g. by an all-reduce).
  std::vector<torch::Tensor> finite_tables;
  // With tables_in_update: the CPU grid tables whose gradient Adam forms inside its update
  // (Adam::TableStep), their lookups still deferred and their decay not yet in loss or terms.
  std::vector<Adam::TableStep> tables;
};

// The distance below which sample tokens' gradients are scaled (ForwardOptions::near_gradient_distance)
// for a scene whose near plane is `near`: the larger of train.near_gradient_distance and
// train.near_gradient_near_multiple x near; 0 = off.
double near_gradient_distance_for(const TrainConfig& tc, double near);

// Runs forward and backward over `batch` in micro-batches of at most `micro` rays; gradients add
// into the parameters' .grad (zero them first), and the grid table's decay (train.grid_decay, its
// share batch / global_rays) once. `distortion_scale` as ray_loss's. Returns the summed loss terms.
// `tables_in_update`: the CPU grid tables' gradients are left to Adam's update (StepSums::tables)
// instead of written to their .grad.
StepSums accumulate_gradients(AbleNerf& model, const RayBatch& batch, int64_t micro, const TrainConfig& tc,
                              int64_t global_rays, double near, double far, const torch::Tensor& distortion_scale = {},
                              bool tables_in_update = false);

}  // namespace ablenerf
