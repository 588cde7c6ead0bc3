#include "kernels/cpu_parallel.h"

#include <ATen/Context.h>
#include <dlfcn.h>

#include <algorithm>
#include <atomic>
#include <cfenv>
#include <chrono>
#include <condition_variable>
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

namespace {

// The threads that take slices 1, 2, ... of parallel_slices, started on first use and kept for the
// process. On a 2-core machine a two-slice call that started and joined its thread took 180 us
// with nothing to do (a training step splits five times); a sleeping thread woken through the
// kernel costs ~30 us each way, so each side first spins briefly (kSpin) on the other's progress
// before it sleeps: 1 us a call (docs/benchmarks/history.md, "Kept slice threads"). One caller at
// a time: a second thread calling parallel_slices while the pool is busy (or a slice splitting
// again) starts threads of its own for that call (slice_threads below). Never destroyed: its
// threads wait for work until the process exits.
class SlicePool {
 public:
  static SlicePool& instance() {
    static SlicePool* pool = new SlicePool();
    return *pool;
  }

  std::mutex& busy() { return busy_; }

  // Runs job(w) for w in [1, workers) on the pool's threads, job(0) on the caller, and returns when
  // all have returned. The caller holds busy().
  void run(int64_t workers, const std::function<void(int64_t)>& job) {
    {
      const std::lock_guard<std::mutex> lock(m_);
      while (static_cast<int64_t>(threads_.size()) < workers - 1) {
        const int64_t index = static_cast<int64_t>(threads_.size()) + 1;
        threads_.emplace_back([this, index] { serve(index); });
        threads_.back().detach();
      }
      job_ = &job;
      job_workers_ = workers;
      pending_.store(workers - 1);
      generation_.fetch_add(1);
    }
    work_.notify_all();
    job(0);
    if (!spin_until([&] { return pending_.load() == 0; })) {
      std::unique_lock<std::mutex> lock(m_);
      done_.wait(lock, [&] { return pending_.load() == 0; });
    }
  }

 private:
  static constexpr std::chrono::microseconds kSpin{100};

  SlicePool() = default;

  // Polls ready() for up to kSpin; true once it holds.
  template <class Ready>
  static bool spin_until(Ready&& ready) {
    const auto until = std::chrono::steady_clock::now() + kSpin;
    while (!ready()) {
      if (std::chrono::steady_clock::now() > until) return false;
      std::this_thread::yield();
    }
    return true;
  }

  void serve(int64_t index) {
    uint64_t seen = 0;
    for (;;) {
      if (!spin_until([&] { return generation_.load() != seen; })) {
        std::unique_lock<std::mutex> lock(m_);
        work_.wait(lock, [&] { return generation_.load() != seen; });
      }
      const std::function<void(int64_t)>* job = nullptr;
      {
        const std::lock_guard<std::mutex> lock(m_);
        seen = generation_.load();
        if (index < job_workers_) job = job_;
      }
      if (job == nullptr) continue;
      (*job)(index);
      if (pending_.fetch_sub(1) == 1) {
        const std::lock_guard<std::mutex> lock(m_);
        done_.notify_one();
      }
    }
  }

  std::mutex busy_;
  std::mutex m_;
  std::condition_variable work_, done_;
  std::vector<std::thread> threads_;
  const std::function<void(int64_t)>* job_ = nullptr;
  int64_t job_workers_ = 0;
  std::atomic<int64_t> pending_{0};
  std::atomic<uint64_t> generation_{0};
};

// job(w) for w in [1, workers) on threads started for this call, job(0) on the caller.
void slice_threads(int64_t workers, const std::function<void(int64_t)>& job) {
  std::vector<std::thread> threads;
  threads.reserve(static_cast<size_t>(workers - 1));
  for (int64_t w = 1; w < workers; ++w) threads.emplace_back([&job, w] { job(w); });
  job(0);
  for (auto& t : threads) t.join();
}

}  // namespace

void parallel_slices(int64_t n, int64_t workers, const std::function<void(int64_t, int64_t, int64_t)>& fn) {
  workers = std::max<int64_t>(1, std::min(workers, n));
  if (workers == 1) {
    fn(0, 0, n);
    return;
  }
  SingleThreadedBlas single;
  // Grad and inference modes are thread-local, and so is the floating-point environment (the
  // subnormal flush): each slice's thread takes the caller's.
  const bool inference = c10::InferenceMode::is_enabled();
  const bool grad = torch::GradMode::is_enabled();
  std::fenv_t env;
  std::fegetenv(&env);
  std::mutex error_mutex;
  std::exception_ptr error;
  const std::function<void(int64_t)> job = [&](int64_t w) {
    try {
      if (w > 0) std::fesetenv(&env);
      c10::InferenceMode inference_guard(inference);
      torch::AutoGradMode grad_guard(grad);
      const WorkerScope scope;
      fn(w, n * w / workers, n * (w + 1) / workers);
    } catch (...) {
      const std::lock_guard<std::mutex> lock(error_mutex);
      if (!error) error = std::current_exception();
    }
  };
  SlicePool& pool = SlicePool::instance();
  std::unique_lock<std::mutex> busy(pool.busy(), std::try_to_lock);
  if (busy.owns_lock()) {
    pool.run(workers, job);
  } else {
    slice_threads(workers, job);
  }
  if (error) std::rethrow_exception(error);
}

int64_t index_count(const IndexRanges& ranges) {
  int64_t n = 0;
  for (const auto& r : ranges) n += r.second - r.first;
  return n;
}

void parallel_ranges(const IndexRanges& ranges, int64_t workers,
                     const std::function<void(int64_t w, int64_t lo, int64_t hi)>& fn) {
  // Each range's start in the concatenation.
  std::vector<int64_t> starts;
  int64_t total = 0;
  for (const auto& r : ranges) {
    starts.push_back(total);
    total += r.second - r.first;
  }
  if (total == 0) return;
  parallel_slices(total, workers, [&](int64_t w, int64_t lo, int64_t hi) {
    // The range holding concatenated index lo, then on through the ones [lo, hi) meets.
    auto k = static_cast<size_t>(std::upper_bound(starts.begin(), starts.end(), lo) - starts.begin()) - 1;
    for (int64_t at = lo; at < hi; ++k) {
      const int64_t end = std::min(hi, starts[k] + (ranges[k].second - ranges[k].first));
      if (end > at) fn(w, ranges[k].first + (at - starts[k]), ranges[k].first + (end - starts[k]));
      at = std::max(at, end);
    }
  });
}

}  // namespace ablenerf
