#include "train/distributed.h"

#include <chrono>
#include <cstdlib>

#include "util/errors.h"

#include <torch/version.h>

#ifdef ABLENERF_HAVE_C10D
#include <torch/csrc/distributed/c10d/ProcessGroupGloo.hpp>
#include <torch/csrc/distributed/c10d/TCPStore.hpp>
#endif
#ifdef ABLENERF_HAVE_NCCL
#include <c10/cuda/CUDAFunctions.h>
#include <torch/csrc/distributed/c10d/ProcessGroupNCCL.hpp>
#endif

namespace ablenerf {

namespace {

int env_int(const char* name, int fallback) {
  const char* v = std::getenv(name);
  if (!v || !*v) return fallback;
  char* end = nullptr;
  const long x = std::strtol(v, &end, 10);
  if (*end != '\0' || x < 0 || x > 1 << 20)
    throw InputError("environment", name, std::string("expected a non-negative integer, got '") + v + "'");
  return static_cast<int>(x);
}

}  // namespace

DistEnv DistEnv::from_environment() {
  DistEnv e;
  e.world_size = env_int("WORLD_SIZE", 1);
  e.rank = env_int("RANK", 0);
  e.local_rank = env_int("LOCAL_RANK", e.rank);
  e.master_port = env_int("MASTER_PORT", 29500);
  e.launched = std::getenv("WORLD_SIZE") != nullptr;
  if (const char* a = std::getenv("MASTER_ADDR"); a && *a) e.master_addr = a;
  if (e.world_size < 1) throw InputError("environment", "WORLD_SIZE", "must be >= 1");
  if (e.rank >= e.world_size)
    throw InputError("environment", "RANK", "must be < WORLD_SIZE (" + std::to_string(e.world_size) + ")");
  if (e.master_port < 1 || e.master_port > 65535) throw InputError("environment", "MASTER_PORT", "not a port");
  return e;
}

#ifdef ABLENERF_HAVE_C10D

namespace {

// The collective interface both backends implement (LibTorch 2 split it out of ProcessGroup).
#if TORCH_VERSION_MAJOR >= 2
using CollectiveBackend = c10d::Backend;
#else
using CollectiveBackend = c10d::ProcessGroup;
#endif

class C10dGroup : public Distributed {
 public:
  C10dGroup(const DistEnv& env, const std::string& backend, double timeout_s) : env_(env) {
    const auto timeout = std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000));
    c10d::TCPStoreOptions so;
    so.port = static_cast<uint16_t>(env.master_port);
    so.isServer = env.rank == 0;
    so.numWorkers = env.world_size;
    so.timeout = timeout;
    try {
      store_ = c10::make_intrusive<c10d::TCPStore>(env.master_addr, so);
    } catch (const std::exception& e) {
      throw std::runtime_error("rank " + std::to_string(env.rank) + ": rendezvous at " + env.master_addr + ":" +
                               std::to_string(env.master_port) + " failed: " + first_line(e.what()));
    }
    if (backend == "nccl") {
#ifdef ABLENERF_HAVE_NCCL
      // One GPU per process: LOCAL_RANK picks it (the trainer puts the model there too).
      c10::cuda::set_device(static_cast<c10::DeviceIndex>(env.local_rank));
      auto opts = c10d::ProcessGroupNCCL::Options::create();
      opts->timeout = timeout;
      pg_ = c10::make_intrusive<c10d::ProcessGroupNCCL>(store_, env.rank, env.world_size, opts);
      on_host_ = false;
#endif
    } else {
      auto opts = c10d::ProcessGroupGloo::Options::create(timeout);
      // Loopback rendezvous (one machine): bind Gloo to loopback too; otherwise to this host's address.
      const bool local = env.master_addr == "localhost" || env.master_addr.rfind("127.", 0) == 0;
      opts->devices.push_back(local ? c10d::ProcessGroupGloo::createDeviceForHostname("127.0.0.1")
                                    : c10d::ProcessGroupGloo::createDefaultDevice());
      pg_ = c10::make_intrusive<c10d::ProcessGroupGloo>(store_, env.rank, env.world_size, opts);
    }
  }

  int rank() const override { return env_.rank; }
  int world_size() const override { return env_.world_size; }

  void broadcast_parameters(AbleNerf& model) override {
    torch::NoGradGuard ng;
    for (auto& bucket : buckets(model->parameters(), false)) {
      auto flat = staged(torch::cat(bucket.views));
      std::vector<at::Tensor> ts{flat};
      wait(pg_->broadcast(ts), "broadcast of the initial weights");
      scatter(flat, bucket);
    }
  }

  void all_reduce_gradients(AbleNerf& model, double* stats, int n) override {
    torch::NoGradGuard ng;
    auto bs = buckets(model->parameters(), true);
    for (size_t b = 0; b < bs.size(); ++b) {
      std::vector<torch::Tensor> parts = bs[b].views;
      if (b + 1 == bs.size())
        parts.push_back(torch::from_blob(stats, {n}, torch::kDouble).to(parts.front().device(), torch::kFloat));
      auto flat = staged(torch::cat(parts));
      std::vector<at::Tensor> ts{flat};
      wait(pg_->allreduce(ts), "gradient all-reduce");
      scatter(flat, bs[b]);
      if (b + 1 == bs.size()) {
        auto tail = flat.slice(0, flat.size(0) - n).to(torch::kDouble);
        for (int i = 0; i < n; ++i) stats[i] = tail[i].item<double>();
      }
    }
  }

  void barrier() override {
    auto t = on_host_ ? torch::zeros({1}) : torch::zeros({1}, torch::Device(torch::kCUDA, env_.local_rank));
    std::vector<at::Tensor> ts{t};
    wait(pg_->allreduce(ts), "barrier");
  }

 private:
  struct Bucket {
    std::vector<torch::Tensor> targets;  // the tensors written back
    std::vector<torch::Tensor> views;    // their flattened values
  };

  static std::string first_line(const std::string& s) { return s.substr(0, s.find('\n')); }

  // Gloo reduces host memory; NCCL reduces the tensors where they are (the GPU).
  torch::Tensor staged(const torch::Tensor& t) const { return on_host_ ? t.cpu().contiguous() : t.contiguous(); }

  // Groups parameters (or their gradients) into buckets of about kBucketBytes.
  static std::vector<Bucket> buckets(const std::vector<torch::Tensor>& params, bool grads) {
    std::vector<Bucket> out(1);
    int64_t bytes = 0;
    for (const auto& p : params) {
      torch::Tensor t = grads ? p.grad() : p;
      if (grads && !t.defined()) continue;  // unused parameter this step: nothing to reduce
      if (bytes > 0 && bytes + t.numel() * 4 > kBucketBytes) {
        out.emplace_back();
        bytes = 0;
      }
      out.back().targets.push_back(t);
      out.back().views.push_back(t.reshape({-1}));
      bytes += t.numel() * 4;
    }
    return out;
  }

  static void scatter(const torch::Tensor& flat, Bucket& b) {
    int64_t off = 0;
    for (auto& t : b.targets) {
      t.copy_(flat.slice(0, off, off + t.numel()).view_as(t));
      off += t.numel();
    }
  }

  void wait(const c10::intrusive_ptr<c10d::Work>& work, const char* what) {
    try {
      work->wait();
    } catch (const std::exception& e) {
      throw std::runtime_error("rank " + std::to_string(env_.rank) + ": " + what +
                               " failed (another process of the group died or timed out): " + first_line(e.what()));
    }
  }

  DistEnv env_;
  bool on_host_ = true;
  c10::intrusive_ptr<c10d::Store> store_;
  c10::intrusive_ptr<CollectiveBackend> pg_;
};

}  // namespace

std::unique_ptr<Distributed> Distributed::join(const DistEnv& env, const std::string& backend, double timeout_s) {
#ifdef ABLENERF_HAVE_NCCL
  const bool nccl_built = true;
#else
  const bool nccl_built = false;
#endif
  if (backend == "nccl" && !nccl_built)
    throw InputError("train", "--dist-backend",
                     "nccl is not available in this build (it needs a CUDA LibTorch with NCCL; gloo is available)");
  if (backend != "gloo" && backend != "nccl")
    throw InputError("train", "--dist-backend", "'" + backend + "': expected gloo or nccl");
  return std::make_unique<C10dGroup>(env, backend, timeout_s);
}

#else

std::unique_ptr<Distributed> Distributed::join(const DistEnv&, const std::string&, double) {
  throw InputError("train", "WORLD_SIZE", "this build has no c10d/Gloo support (install libgloo-dev and rebuild)");
}

#endif

}  // namespace ablenerf
