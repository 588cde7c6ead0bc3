#pragma once
// Adam's update of one float32 parameter on the CPU, element by element (Kingma & Ba 2015, as
// torch::optim::Adam in LibTorch 1.13 without weight decay or amsgrad):
//   m = m b1 + (1 - b1) g
//   v = v b2 + (1 - b2) g^2
//   w = w + neg_step m / (sqrt(v) / sqrt_bias2 + eps)
// with the bias corrections folded into neg_step = -lr / (1 - b1^t) and sqrt_bias2 = sqrt(1 - b2^t)
// by the caller (train/adam.h, which keeps the state). Every form does the same float32 operations
// in the same order, without fused multiply-adds, so the forms agree to the bit; the vector form
// does 16 elements per instruction (the tables of the grid front end are a million entries, and
// the scalar loop compiled for the baseline x86-64 did four).
#include <cstdint>

#include "kernels/cpu_features.h"

namespace ablenerf {

struct AdamScalars {
  float b1, one_b1, b2, one_b2, eps, sqrt_bias2, neg_step;
};

// Elements [0, n) of g (gradient), m, v (moments) and w (parameter); m, v, w updated in place.
// A form that cannot run here throws std::invalid_argument.
void adam_update_cpu_in(CpuVectorForm form, int64_t n, const float* g, float* m, float* v, float* w,
                        const AdamScalars& s);
void adam_update_cpu(int64_t n, const float* g, float* m, float* v, float* w, const AdamScalars& s);

// The update of a grid table's entries whose gradient is formed on the way (kernels/table_gradient.h):
// g = sum + two_decay x w (the weight decay's term on the scattered lookups), then the update above:
// the same float32 operations as that sum followed by adam_update_cpu, to the bit, in one pass over
// the memory instead of a gradient written and read again. Returns the sum of w^2 before the update
// in float64 (the decay's value); an entry whose g is not finite is left as it is (w, m and v) and
// clears `finite`.
double adam_update_decayed_cpu_in(CpuVectorForm form, int64_t n, const float* sum, float two_decay, float* m, float* v,
                                  float* w, const AdamScalars& s, bool& finite);

}  // namespace ablenerf
