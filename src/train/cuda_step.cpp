#include "train/cuda_step.h"

#include <torch/version.h>

#include <stdexcept>

#if defined(ABLENERF_WITH_CUDA) && TORCH_VERSION_MAJOR >= 2
#include <ATen/cuda/CUDAEvent.h>
#include <ATen/cuda/CUDAGraph.h>
#include <c10/cuda/CUDAGuard.h>
#include <c10/cuda/CUDAStream.h>
#define ABLENERF_CUDA_STEP 1
#endif

namespace ablenerf {

#ifdef ABLENERF_CUDA_STEP

namespace {
constexpr int kSlots = 2;  // double buffering: a slot is rewritten only after its last copy is done
}

struct CudaStep::Impl {
  Impl(const torch::Device& d, bool use_graph, int64_t warmup)
      : device(d),
        graph_wanted(use_graph),
        warmup_left(warmup),
        stream(c10::cuda::getStreamFromPool(/*isHighPriority=*/false, d.index() < 0 ? 0 : d.index())) {
    // Work queued on the previous stream (data and weights uploads) completes before this stream
    // starts using it.
    c10::cuda::getCurrentCUDAStream(stream.device_index()).synchronize();
    guard.emplace(stream);
  }
  torch::Device device;
  bool graph_wanted;
  int64_t warmup_left;
  c10::cuda::CUDAStream stream;
  std::optional<c10::cuda::CUDAStreamGuard> guard;
  std::optional<at::cuda::CUDAGraph> graph;
  bool captured = false;
  // Staging: pinned host buffers and the events that say when a slot's copy is done.
  torch::Tensor up_host[kSlots];
  at::cuda::CUDAEvent up_done[kSlots];
  int64_t uploads = 0;
  torch::Tensor down_host[kSlots];
  at::cuda::CUDAEvent down_done[kSlots];
  int64_t downloads = 0;
};

bool CudaStep::available(const torch::Device& device) { return device.is_cuda(); }

CudaStep::CudaStep(const torch::Device& device, bool graph, int64_t warmup_steps)
    : impl_(std::make_unique<Impl>(device, graph, warmup_steps)) {}

CudaStep::~CudaStep() {
  if (impl_) impl_->stream.synchronize();
}

void CudaStep::upload(const torch::Tensor& host, torch::Tensor& device_tensor) {
  auto& m = *impl_;
  const int s = static_cast<int>(m.uploads % kSlots);
  if (m.uploads >= kSlots) m.up_done[s].synchronize();  // that slot's last copy has been read
  if (!m.up_host[s].defined() || m.up_host[s].sizes() != host.sizes() || m.up_host[s].dtype() != host.dtype())
    m.up_host[s] = torch::empty(host.sizes(), host.options().pinned_memory(true));
  m.up_host[s].copy_(host);
  device_tensor.copy_(m.up_host[s], /*non_blocking=*/true);
  m.up_done[s].record(m.stream);
  ++m.uploads;
}

void CudaStep::run(const std::function<void()>& body, const std::function<void()>& before_eager) {
  auto& m = *impl_;
  if (m.captured) {
    m.graph->replay();
    return;
  }
  before_eager();
  if (!m.graph_wanted || m.warmup_left > 0) {
    // Eager steps on this stream first: they create the libraries' workspaces and plans that
    // the capture then reuses.
    body();
    if (m.warmup_left > 0) --m.warmup_left;
    return;
  }
  m.stream.synchronize();
  m.graph.emplace();
  m.graph->capture_begin();
  body();
  m.graph->capture_end();
  m.captured = true;
  m.graph->replay();  // capturing records the work without running it
}

bool CudaStep::captured() const { return impl_->captured; }

void CudaStep::queue(const torch::Tensor& values) {
  auto& m = *impl_;
  const int s = static_cast<int>(m.downloads % kSlots);
  if (m.downloads >= kSlots) m.down_done[s].synchronize();
  const auto flat = values.detach().reshape({-1}).to(torch::kDouble);
  if (!m.down_host[s].defined() || m.down_host[s].numel() != flat.numel())
    m.down_host[s] = torch::empty({flat.numel()}, torch::TensorOptions().dtype(torch::kDouble).pinned_memory(true));
  m.down_host[s].copy_(flat, /*non_blocking=*/true);
  m.down_done[s].record(m.stream);
  ++m.downloads;
}

std::optional<std::vector<double>> CudaStep::take() {
  auto& m = *impl_;
  if (m.downloads == 0) return std::nullopt;
  const int s = static_cast<int>((m.downloads - 1) % kSlots);
  m.down_done[s].synchronize();
  const double* p = m.down_host[s].data_ptr<double>();
  return std::vector<double>(p, p + m.down_host[s].numel());
}

std::optional<std::vector<double>> CudaStep::drain() {
  impl_->stream.synchronize();
  return take();
}

#else  // no CUDA LibTorch >= 2

struct CudaStep::Impl {};

bool CudaStep::available(const torch::Device&) { return false; }

CudaStep::CudaStep(const torch::Device&, bool, int64_t) {
  throw std::logic_error("CudaStep: this build has no CUDA LibTorch >= 2");
}
CudaStep::~CudaStep() = default;
void CudaStep::upload(const torch::Tensor&, torch::Tensor&) {}
void CudaStep::run(const std::function<void()>&, const std::function<void()>&) {}
bool CudaStep::captured() const { return false; }
void CudaStep::queue(const torch::Tensor&) {}
std::optional<std::vector<double>> CudaStep::take() { return std::nullopt; }
std::optional<std::vector<double>> CudaStep::drain() { return std::nullopt; }

#endif

}  // namespace ablenerf
