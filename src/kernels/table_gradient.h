#pragma once
// A hash grid table's gradient gathered outside autograd on the CPU: the grid's table
// (kernels/hash_grid.h) in a training step.
//
// Why: through autograd every use of the table returns a gradient the table's size, zero-filled
// before the scatter, then added use to use (the grid is read by the coarse and the fine pass),
// thread to thread (the ray split, kernels/cpu_parallel.h) and to the weight decay's term: six
// passes over a 5 MiB table per step at the capture preset. Scattering each thread's lookups into
// a buffer of its own still made the step sweep the table's size three times over in memory (the
// scatters, the sum of the buffers, their zeroing) before Adam's pass.
//
// How: a thread that opens a TableGradientScope(k) has every table lookup it differentiates hand
// its scatter (the points and the gradient of their features) to the table's TableGradient under
// the key k; autograd sees no gradient for the table. After the threads have joined, finish()
// builds the parameter's .grad (a buffer kept from step to step) level by level, the levels shared
// among the CPU's threads: a level's rows set to 0, every deferred scatter added into them while
// they stay in the core's cache (keys in order, each key's lookups in the order they came), then
// the decay's term added and the rows checked in one pass. Only the entries a lookup can reach are
// written (a dense level's unused rows stay 0: hash_grid_level_rows); Adam is told the same
// (train/adam.h). The sums differ from autograd's only in the order of the additions.
//
// A single-process CPU training step goes one pass further (finish_adam): each level's summed
// lookups go straight into Adam's update of the level's rows while they are in the cache, and the
// gradient is never written to memory at all. The step's finite check, which must come before any
// update, then reads the lookups' values rather than the table's gradient (lookups_finite).
// Measured at the capture preset: the table's passes (scatter, sum, decay, check, Adam) from 19% of
// the step's samples to 12%, the step 1.05x (docs/benchmarks/history.md, "The table's gradient
// formed inside Adam's update").
#include <torch/torch.h>

#include <mutex>
#include <vector>

#include "kernels/adam_cpu.h"
#include "kernels/cpu_features.h"
#include "kernels/hash_grid_shape.h"

namespace ablenerf {

// A lookup's scatter: grad_out (n, levels, features) of the features at positions (n, 3), times
// scales (n, levels) where defined; float32, contiguous, on the CPU.
struct DeferredLookup {
  torch::Tensor positions, grad_out, scales;
};

class TableGradient {
 public:
  // For a table (levels, table_size, features) of this shape.
  explicit TableGradient(const HashGridShape& shape);

  // The key the calling thread's lookups defer their scatters under, or -1 when it opened none
  // (the autograd path).
  static int current_key();

  // A lookup's scatter under key k (>= 0), kept for finish(); its tensors are held, not copied.
  // Threads may defer at the same time.
  void defer(int k, DeferredLookup lookup);

  // parameter.grad = (parameter.grad if defined) + the deferred scatters + 2 decay x parameter,
  // over the entries a lookup can reach (all of them when a gradient was already there), 0
  // elsewhere; the scatters dropped; returns decay x sum(parameter^2) over those entries (0 without
  // decay). Without a deferred scatter and without decay nothing changes and 0 is returned. Call
  // after the threads that deferred have joined. `form` forces the scalar loops (tests).
  double finish(torch::Tensor& parameter, double decay, CpuVectorForm form = cpu_best_vector_form());

  // Whether the deferred lookups' gradients (and scales) are finite and small enough (the sum of
  // their magnitudes under kLookupBound) that no sum of them can overflow: with a finite parameter,
  // the gradient finish() or finish_adam() would form is then finite. Each lookup's sum is taken
  // when it is deferred, on its thread; this reads none of the table.
  bool lookups_finite() const;
  static constexpr double kLookupBound = 1e30;

  // finish() and Adam's update of the parameter in one pass (kernels/adam_cpu.h,
  // adam_update_decayed_cpu_in) with moments m and v (float32, the parameter's layout): the gradient
  // formed level by level and used at once, never stored; only the entries a lookup can reach are
  // updated. The parameter must hold no gradient. Returns the decay's value as finish() does. An
  // entry whose gradient turns out not finite (possible only with a parameter that is not finite
  // itself, once lookups_finite() held) keeps its values, and wrote_finite_gradient() is false.
  double finish_adam(torch::Tensor& parameter, double decay, const AdamScalars& scalars, float* m, float* v,
                     CpuVectorForm form = cpu_best_vector_form());

  // True when the last finish() (or finish_adam()) formed the parameter's gradient and every entry
  // of it is finite, found in the same pass (so that the optimiser's check need not read the
  // table's gradient again: train/adam.h); false after one that formed nothing, or found an
  // infinite or NaN entry.
  bool wrote_finite_gradient() const { return finite_; }

  // The deferred scatters dropped without a gradient (a step abandoned between its backward and
  // finish()).
  void discard();

  // Whether a scatter is waiting for finish().
  bool pending() const;

 private:
  void check_parameter(const torch::Tensor& parameter) const;
  template <class Done>
  void sum_levels(CpuVectorForm form, const float* g0, bool all, Done&& done);

  HashGridShape shape_;
  mutable std::mutex mutex_;
  struct Deferred {
    int key;
    DeferredLookup lookup;
    double bound;  // the sum of its magnitudes (lookups_finite)
  };
  std::vector<Deferred> deferred_;  // in the order they came
  torch::Tensor grad_;              // the .grad handed out, reused while the parameter keeps its shape
  bool outside_zero_ = false;       // grad_ is 0 outside the entries a lookup reaches
  bool finite_ = false;
};

// Lookups on this thread defer their table gradients under key `k` for the scope (restores the
// previous key after).
class TableGradientScope {
 public:
  explicit TableGradientScope(int k);
  ~TableGradientScope();
  TableGradientScope(const TableGradientScope&) = delete;
  TableGradientScope& operator=(const TableGradientScope&) = delete;

 private:
  int previous_;
};

// finish()'s arithmetic in LibTorch ops, for the tests: grad (undefined = none) + each lookup's
// table gradient in turn (the plain lookup hash_grid_encode_reference, differentiated by autograd)
// + 2 decay x parameter; without grad, 0 outside the entries a lookup can reach.
torch::Tensor table_gradient_reference(const torch::Tensor& grad, const std::vector<DeferredLookup>& lookups,
                                       const torch::Tensor& parameter, const HashGridShape& shape, double decay);

}  // namespace ablenerf
