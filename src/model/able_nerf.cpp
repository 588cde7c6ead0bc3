#include "model/able_nerf.h"

namespace ablenerf {
// Placeholder: replaced by the model implementation.
AbleNerfImpl::AbleNerfImpl(const ModelConfig& cfg) : cfg_(cfg) {}
ModelOutput AbleNerfImpl::forward(const Rays&, double, double, const ForwardOptions&) {
  TORCH_CHECK(false, "model not implemented yet");
}
int64_t AbleNerfImpl::parameter_count() const {
  int64_t n = 0;
  for (const auto& p : parameters()) n += p.numel();
  return n;
}
}  // namespace ablenerf
