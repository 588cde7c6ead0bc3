#pragma once
// A large trainable table's gradient gathered outside autograd on the CPU: the hash grid's table
// (kernels/hash_grid.h) in a training step.
//
// Why: through autograd every use of the table returns a gradient the table's size, zero-filled
// before the scatter, then added use to use (the grid is read by the coarse and the fine pass),
// thread to thread (the ray split, kernels/cpu_parallel.h) and to the weight decay's term: six
// passes over a 5 MiB table per step at the capture preset, where the slots make one. Measured on
// a real capture the step is 1-2% shorter (docs/benchmarks/history.md, "The table's gradient in
// slots"); the slots are also where a pass over only the rows a step touched would start.
//
// How: a thread that opens a TableGradientScope(k) has every table lookup it differentiates
// scatter straight into slot k of that table's TableGradient, a buffer of the table's size that is
// zero between steps; autograd sees no gradient for the table. After the threads have joined,
// finish() writes the sum of the slots, in slot order, plus the decay's gradient into the
// parameter's .grad in one pass (a buffer kept from step to step) and zeroes the slots again.
// The sums differ from autograd's only in the order of the additions.
#include <torch/torch.h>

#include <memory>
#include <mutex>
#include <vector>

#include "kernels/cpu_features.h"
#include "kernels/cpu_parallel.h"

namespace ablenerf {

class TableGradient {
 public:
  // The slot the calling thread's lookups write to, or -1 when it opened none (the autograd path).
  static int current_slot();

  // Slot k's buffer for `table` (float32, contiguous, on the CPU), created zeroed on first use;
  // marks it written. Threads may ask for different slots at the same time.
  float* slot(const torch::Tensor& table, int k);

  // parameter.grad = (parameter.grad if defined) + the slots' sum + 2 decay x parameter, and the
  // slots zeroed; returns decay x sum(parameter^2) (0 without decay). Without a written slot and
  // without decay nothing changes and 0 is returned. Call after the threads that wrote have joined.
  // `form` forces the scalar loop (tests); every form writes the same gradient to the bit.
  double finish(torch::Tensor& parameter, double decay, CpuVectorForm form = cpu_best_vector_form());

  // True when the last finish() wrote the parameter's gradient and every entry of it is finite,
  // found in the same pass (so that the optimiser's check need not read the table's gradient
  // again: train/adam.h); false after one that wrote nothing, or found an infinite or NaN entry.
  bool wrote_finite_gradient() const { return finite_; }

  // The slots zeroed without a gradient (a step abandoned between its backward and finish()).
  void discard();

  // The table's entries a lookup can reach (the grid's own rule: hash_grid_level_rows), or empty for
  // all of them. finish() then sums, decays and checks only those: the others' gradient is 0 (a
  // dense level's unused rows, a quarter of the capture preset's tables), and with Adam told the
  // same (train/adam.h) no pass of the step reads them. Not when the parameter already holds a
  // gradient (every entry is written then).
  void set_entries(IndexRanges entries);

  // Whether a slot holds a gradient finish() has not taken yet.
  bool pending() const;

 private:
  mutable std::mutex mutex_;
  std::vector<torch::Tensor> slots_;
  std::vector<bool> written_;
  torch::Tensor grad_;         // the .grad handed out, reused while the parameter keeps its shape
  bool outside_zero_ = false;  // grad_ is 0 outside entries_
  IndexRanges entries_;
  bool finite_ = false;
};

// Lookups on this thread write their table gradients to slot `k` for the scope (restores the
// previous slot after).
class TableGradientScope {
 public:
  explicit TableGradientScope(int k);
  ~TableGradientScope();
  TableGradientScope(const TableGradientScope&) = delete;
  TableGradientScope& operator=(const TableGradientScope&) = delete;

 private:
  int previous_;
};

// finish()'s arithmetic in LibTorch ops, for the tests: grad (undefined = none) + sum(slots) +
// 2 decay x parameter.
torch::Tensor table_gradient_reference(const torch::Tensor& grad, const std::vector<torch::Tensor>& slots,
                                       const torch::Tensor& parameter, double decay);

}  // namespace ablenerf
