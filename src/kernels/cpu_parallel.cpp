#include "kernels/cpu_parallel.h"

#include <ATen/Context.h>
#include <dlfcn.h>

#include <algorithm>
#include <cstdlib>
#include <exception>
#include <mutex>
#include <thread>
#include <vector>

namespace ablenerf {

namespace {

// Fewest rays per CPU thread in a ray split (below, thread start-up dominates).
constexpr int64_t kMinRaysPerWorker = 8;

// A runtime's thread count, set and read through its two C functions, looked up at run time: other
// BLAS builds (or a LibTorch with MKL or without OpenMP) simply skip the control.
using SetThreads = void (*)(int);
using GetThreads = int (*)();

struct ThreadControl {
  SetThreads set = nullptr;
  GetThreads get = nullptr;
  ThreadControl(const char* set_name, const char* get_name) {
    set = reinterpret_cast<SetThreads>(dlsym(RTLD_DEFAULT, set_name));
    get = reinterpret_cast<GetThreads>(dlsym(RTLD_DEFAULT, get_name));
    if (!set || !get) set = nullptr, get = nullptr;
  }
};

// OpenBLAS's pool (process-wide).
const ThreadControl& blas_threads() {
  static const ThreadControl b("openblas_set_num_threads", "openblas_get_num_threads");
  return b;
}

// OpenMP's per-thread team size (the nthreads-var ICV), which LibTorch's intra-op loops follow.
const ThreadControl& omp_threads() {
  static const ThreadControl o("omp_set_num_threads", "omp_get_max_threads");
  return o;
}

// Set in the threads of a running parallel_slices: nested calls stay serial.
thread_local bool t_in_worker = false;

// LibTorch's thread count before a SerialIntraOp on this thread took it to 1 (0 outside one): it
// still counts in the thread budget, so the ray split inside such a scope keeps its threads.
thread_local int t_held_threads = 0;

// A slice's thread for the scope: nested splits stay serial, and so do LibTorch's own intra-op loops
// (at::parallel_for: element-wise ops over large tensors, the hash grid's kernels). Left alone,
// each slice's thread would open an OpenMP team of its own in those loops, W teams on W cores whose
// idle members spin while the other slices work: on 2 cores a quarter of the capture preset's CPU
// time went to that spinning, and the 256-ray training step took 84 ms against 58 ms with LibTorch
// held to one thread (docs/benchmarks/history.md, "One OpenMP team per slice").
class WorkerScope {
 public:
  WorkerScope() : previous_(t_in_worker) { t_in_worker = true; }
  ~WorkerScope() { t_in_worker = previous_; }
  WorkerScope(const WorkerScope&) = delete;
  WorkerScope& operator=(const WorkerScope&) = delete;

 private:
  bool previous_;
  SerialIntraOp serial_;
};

}  // namespace

SerialIntraOp::SerialIntraOp() {
  const auto& omp = omp_threads();
  if (!omp.set) return;
  // at::get_num_threads() first: a thread's first call into LibTorch's parallel code sets its team
  // size from the process's count, which would undo the 1 set here.
  (void)at::get_num_threads();
  previous_ = omp.get();
  held_ = t_held_threads;
  t_held_threads = std::max(held_, previous_);
  if (previous_ != 1) omp.set(1);
}

SerialIntraOp::~SerialIntraOp() {
  if (previous_ > 1) omp_threads().set(previous_);
  t_held_threads = held_;
}

SingleThreadedBlas::SingleThreadedBlas() {
  const auto& b = blas_threads();
  if (b.set) {
    previous_ = b.get();
    if (previous_ != 1) b.set(1);
  }
}

SingleThreadedBlas::~SingleThreadedBlas() {
  const auto& b = blas_threads();
  if (b.set && previous_ > 1) b.set(previous_);
}

int64_t ray_workers(int64_t rays) { return cpu_workers(rays, kMinRaysPerWorker); }

bool blas_thread_control_available() { return blas_threads().set != nullptr; }

int64_t cpu_thread_budget() {
  const auto& blas = blas_threads();
  return std::max<int64_t>({1, at::get_num_threads(), t_held_threads, blas.get ? blas.get() : 1});
}

int64_t cpu_workers(int64_t n, int64_t min_per_worker) {
  if (!blas_thread_control_available() || t_in_worker) return 1;
  return std::max<int64_t>(1, std::min(cpu_thread_budget(), n / std::max<int64_t>(1, min_per_worker)));
}

std::string blas_core_name() {
  using CoreName = char* (*)();
  const auto name = reinterpret_cast<CoreName>(dlsym(RTLD_DEFAULT, "openblas_get_corename"));
  const char* n = name ? name() : nullptr;
  return n ? std::string(n) : std::string();
}

std::string blas_core_override() {
#if defined(__x86_64__)
  if (std::getenv("OPENBLAS_CORETYPE")) return "";
  if (blas_core_name() != "Prescott") return "";
  __builtin_cpu_init();
  if (!__builtin_cpu_supports("avx2") || !__builtin_cpu_supports("fma")) return "";
  const bool avx512 = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512dq") &&
                      __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl");
  return avx512 ? "SkylakeX" : "Haswell";
#else
  return "";
#endif
}

bool flush_subnormals() { return at::globalContext().setFlushDenormal(true); }

void parallel_slices(int64_t n, int64_t workers, const std::function<void(int64_t, int64_t, int64_t)>& fn) {
  workers = std::max<int64_t>(1, std::min(workers, n));
  if (workers == 1) {
    fn(0, 0, n);
    return;
  }
  SingleThreadedBlas single;
  const bool inference = c10::InferenceMode::is_enabled();
  const bool grad = torch::GradMode::is_enabled();
  std::mutex error_mutex;
  std::exception_ptr error;
  const auto run = [&](int64_t w) {
    try {
      const WorkerScope scope;
      fn(w, n * w / workers, n * (w + 1) / workers);
    } catch (...) {
      const std::lock_guard<std::mutex> lock(error_mutex);
      if (!error) error = std::current_exception();
    }
  };
  std::vector<std::thread> threads;
  threads.reserve(static_cast<size_t>(workers - 1));
  for (int64_t w = 1; w < workers; ++w)
    threads.emplace_back([&, w] {
      // Grad and inference modes are thread-local: mirror the caller's.
      c10::InferenceMode inference_guard(inference);
      torch::AutoGradMode grad_guard(grad);
      run(w);
    });
  run(0);
  for (auto& t : threads) t.join();
  if (error) std::rethrow_exception(error);
}

}  // namespace ablenerf
