#pragma once
// The optimiser of a training step: Adam without weight decay, betas (0.9, 0.999) and eps 1e-8 by
// default (docs/MODEL.md, section 8; train.adam_beta1 / adam_beta2 / adam_eps), in one of two forms over one state:
//  - host form (any device, any LibTorch): the learning rate and step count live on the host, and
//    a step whose loss or gradients are not finite is skipped by a check that synchronises with
//    the device. With CPU float32 parameters the check and the update are two plain loops over
//    the parameters' memory (the arithmetic of torch::optim::Adam, on its own state tensors);
//    otherwise torch::optim::Adam itself. Why: at the demo preset's size torch::optim::Adam and
//    the finite check issue ~1,000 LibTorch ops per step over 120 small tensors, a few
//    milliseconds of dispatch on 2 CPU cores for ~0.2 ms of arithmetic;
//  - device form (CUDA, LibTorch >= 2): one multi-tensor kernel (at::_fused_adam_) that reads the
//    learning rate and the step count from device memory, after an on-device finite check
//    (found_inf) that makes the kernel skip the update and leaves the step count alone. Nothing
//    in it synchronises with the host, so it can run inside a CUDA graph.
// Checkpoints always save and load the torch::optim::Adam (optim()); the device form copies its
// step count there before a save (to_checkpoint) and rebinds its state after a load
// (from_checkpoint), so a resumed run continues exactly.
#include <torch/torch.h>

#include <memory>
#include <unordered_map>
#include <vector>

#include "kernels/adam_cpu.h"
#include "kernels/cpu_parallel.h"
#include "kernels/table_gradient.h"

namespace ablenerf {

// Adam's constants (TrainConfig's adam_* keys).
struct AdamSettings {
  double beta1 = 0.9, beta2 = 0.999, eps = 1e-8;
};

class Adam {
 public:
  Adam(std::vector<torch::Tensor> params, double lr, bool device_form, const AdamSettings& settings = {});

  // True when the device form is available here (CUDA parameters, LibTorch >= 2 with CUDA).
  static bool device_form_available(const torch::Device& device);

  bool device_form() const { return device_form_; }
  // True when step_host runs the plain loops (every parameter a contiguous CPU float32 tensor).
  bool host_loops() const { return host_loops_; }
  torch::optim::Adam& optim() { return optim_; }
  // p's state in optim() (its moments and step count); throws std::out_of_range before p's first step.
  torch::optim::AdamParamState& state_of(const torch::Tensor& p);

  void set_lr(double lr);  // host form: the options; device form: an asynchronous fill
  void clear_grads();      // every .grad undefined (the next backward writes fresh buffers)

  // A grid table whose gradient is never stored: its deferred lookups (kernels/table_gradient.h)
  // are summed level by level inside its update (TableGradient::finish_adam), with its weight
  // decay's term (`decay`, the coefficient: train/regularisers.h). The parameter holds no .grad.
  struct TableStep {
    torch::Tensor param;
    TableGradient* gradient = nullptr;
    double decay = 0.0;
    double value = 0.0;  // out: the decay's value (decay x the sum of squares), 0 when skipped
  };

  // Host form: when `loss` and every gradient are finite, updates and returns true; otherwise
  // returns false without updating (the caller clears the gradients). `checked`: parameters whose
  // gradient the caller has already found finite in a pass of its own (a grid table's, in the pass
  // that gathers it: kernels/table_gradient.h); the check does not read those again. `tables`
  // (host loops only): updated after the others, when their lookups are finite too
  // (TableGradient::lookups_finite); their lookups are consumed either way. Returns false, the
  // others updated, in the one case the tables' own pass finds a gradient that is not finite (a
  // table that is not finite itself).
  bool step_host(double loss, const std::vector<torch::Tensor>& checked = {}, std::vector<TableStep>* tables = nullptr);

  // Device form: sets found_inf() to 1 when `loss` or a gradient is not finite, else 0, then
  // updates unless it is 1. Capturable.
  void step_device(const torch::Tensor& loss);
  const torch::Tensor& found_inf() const { return found_inf_; }

  // Host loops only: `param`'s update touches only these entries (a grid table's entries a lookup
  // can reach: kernels/table_gradient.h), the others and their moments left as they are. Empty: all.
  void set_entries(const torch::Tensor& param, IndexRanges entries);

  void to_checkpoint();  // device form: the step count into optim()'s per-parameter state
  // After a load: this run's settings over the ones the checkpoint's options carried (a resumed
  // run follows its own config); device form: rebind the state tensors optim() holds.
  void from_checkpoint();

 private:
  void bind_state();
  // grads: each parameter's gradient, contiguous, or undefined where it has none.
  static bool gradients_finite_loop(const std::vector<torch::Tensor>& grads);
  void update_loop(const std::vector<torch::Tensor>& grads);
  bool update_tables(std::vector<TableStep>& tables);
  // p's state advanced by one step (created on its first) and the scalars of its update.
  torch::optim::AdamParamState& advance(const torch::Tensor& p, AdamScalars& scalars);

  std::vector<torch::Tensor> params_;
  std::unordered_map<const void*, IndexRanges> entries_;  // set_entries, by the parameter's TensorImpl
  AdamSettings settings_;
  torch::optim::Adam optim_;
  bool device_form_;
  bool host_loops_ = false;
  // Device form: the state the kernel updates (the same tensors optim_ holds), one step count
  // shared by every parameter, the learning rate and the finite flag, all on the device.
  std::vector<torch::Tensor> exp_avg_, exp_avg_sq_;
  torch::Tensor step_, lr_, found_inf_;
};

}  // namespace ablenerf
