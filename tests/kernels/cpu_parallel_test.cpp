// Ray-parallel CPU execution (kernels/cpu_parallel.h): slices cover the range once, errors come
// back to the caller, nested calls stay serial, thread-local modes are mirrored, and BLAS's and
// LibTorch's thread counts are single inside and restored after; subnormal floats flush to zero
// on the caller and in the slices' threads, which follow the caller's mode at every call;
// concurrent callers each get their own range.
#include <ATen/Context.h>
#include <dlfcn.h>
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <algorithm>
#include <atomic>
#include <mutex>
#include <set>
#include <stdexcept>
#include <thread>
#include <vector>

#include "kernels/cpu_parallel.h"

namespace ablenerf {
namespace {

int openblas_threads() {
  using Get = int (*)();
  const auto get = reinterpret_cast<Get>(dlsym(RTLD_DEFAULT, "openblas_get_num_threads"));
  return get ? get() : -1;
}

struct Slice {
  int64_t w, lo, hi;
  std::thread::id thread;
};

TEST(CpuParallel, SlicesCoverTheRangeOnceInOrder) {
  for (const int64_t workers : {1, 2, 3, 5}) {
    std::mutex m;
    std::vector<Slice> seen;
    parallel_slices(37, workers, [&](int64_t w, int64_t lo, int64_t hi) {
      const std::lock_guard<std::mutex> lock(m);
      seen.push_back({w, lo, hi, std::this_thread::get_id()});
    });
    ASSERT_EQ(static_cast<int64_t>(seen.size()), workers);
    std::sort(seen.begin(), seen.end(), [](const Slice& a, const Slice& b) { return a.w < b.w; });
    int64_t next = 0;
    std::set<std::thread::id> threads;
    for (int64_t i = 0; i < workers; ++i) {
      EXPECT_EQ(seen[i].w, i);
      EXPECT_EQ(seen[i].lo, next);
      EXPECT_GE(seen[i].hi - seen[i].lo, 37 / workers);  // balanced: 7 or 8 for 5 workers
      EXPECT_LE(seen[i].hi - seen[i].lo, 37 / workers + 1);
      next = seen[i].hi;
      threads.insert(seen[i].thread);
    }
    EXPECT_EQ(next, 37);
    EXPECT_EQ(static_cast<int64_t>(threads.size()), workers);  // one thread per slice
    EXPECT_EQ(seen[0].thread, std::this_thread::get_id());     // the caller takes slice 0
  }
}

// parallel_ranges: every index of the ranges once, each call inside one range, the workers' shares
// of the indices balanced, empty ranges and gaps skipped.
TEST(CpuParallel, RangesCoverTheirIndicesOnceEachCallInsideOneRange) {
  const IndexRanges ranges{{3, 10}, {10, 10}, {20, 21}, {40, 73}, {73, 80}};
  ASSERT_EQ(index_count(ranges), 48);
  for (const int64_t workers : {1, 2, 3, 7}) {
    std::mutex m;
    std::vector<Slice> seen;
    parallel_ranges(ranges, workers, [&](int64_t w, int64_t lo, int64_t hi) {
      const std::lock_guard<std::mutex> lock(m);
      seen.push_back({w, lo, hi, std::this_thread::get_id()});
    });
    std::vector<int> hits(80, 0);
    std::vector<int64_t> share(static_cast<size_t>(workers), 0);
    for (const Slice& s : seen) {
      ASSERT_LT(s.lo, s.hi);
      const bool inside =
          std::any_of(ranges.begin(), ranges.end(), [&](const auto& r) { return r.first <= s.lo && s.hi <= r.second; });
      EXPECT_TRUE(inside) << s.lo << ".." << s.hi;
      for (int64_t i = s.lo; i < s.hi; ++i) hits[static_cast<size_t>(i)]++;
      share[static_cast<size_t>(s.w)] += s.hi - s.lo;
    }
    for (int64_t i = 0; i < 80; ++i) {
      const bool in =
          std::any_of(ranges.begin(), ranges.end(), [&](const auto& r) { return r.first <= i && i < r.second; });
      EXPECT_EQ(hits[static_cast<size_t>(i)], in ? 1 : 0) << "index " << i << " workers " << workers;
    }
    for (const int64_t n : share) {
      EXPECT_GE(n, 48 / workers);
      EXPECT_LE(n, 48 / workers + 1);
    }
  }
  int calls = 0;
  parallel_ranges({}, 2, [&](int64_t, int64_t, int64_t) { ++calls; });
  parallel_ranges({{5, 5}}, 2, [&](int64_t, int64_t, int64_t) { ++calls; });
  EXPECT_EQ(calls, 0);
}

TEST(CpuParallel, MoreWorkersThanItemsUsesOnePerItem) {
  std::atomic<int> calls{0};
  parallel_slices(2, 8, [&](int64_t, int64_t lo, int64_t hi) {
    EXPECT_EQ(hi - lo, 1);
    ++calls;
  });
  EXPECT_EQ(calls.load(), 2);
}

TEST(CpuParallel, WorkerErrorsReachTheCallerAfterAllSlicesRan) {
  std::atomic<int> finished{0};
  EXPECT_THROW(parallel_slices(10, 3,
                               [&](int64_t w, int64_t, int64_t) {
                                 if (w == 2) throw std::runtime_error("slice 2 failed");
                                 ++finished;
                               }),
               std::runtime_error);
  EXPECT_EQ(finished.load(), 2);
}

TEST(CpuParallel, ModesMirroredNestingSerialBlasRestored) {
  if (!blas_thread_control_available()) GTEST_SKIP() << "no OpenBLAS thread control in this build";
  const int blas_before = openblas_threads();
  for (const bool grad : {true, false}) {
    torch::AutoGradMode mode(grad);
    std::atomic<int> ok{0};
    parallel_slices(64, 2, [&](int64_t, int64_t, int64_t) {
      if (torch::GradMode::is_enabled() == grad && openblas_threads() == 1 && cpu_workers(1000, 1) == 1) ++ok;
    });
    EXPECT_EQ(ok.load(), 2) << "grad " << grad;
  }
  {
    c10::InferenceMode inference;
    std::atomic<int> ok{0};
    parallel_slices(64, 2, [&](int64_t, int64_t, int64_t) { ok += c10::InferenceMode::is_enabled() ? 1 : 0; });
    EXPECT_EQ(ok.load(), 2);
  }
  EXPECT_EQ(openblas_threads(), blas_before);
}

// LibTorch's own loops (compiled with OpenMP inside libtorch) size their teams by the thread's
// at::get_num_threads(): one inside every slice, the caller's count again after.
TEST(CpuParallel, LibTorchThreadsAreOneInsideSlicesAndComeBack) {
  if (!dlsym(RTLD_DEFAULT, "omp_set_num_threads")) GTEST_SKIP() << "LibTorch without OpenMP in this build";
  const int before = at::get_num_threads();
  at::set_num_threads(2);
  std::atomic<int> serial{0};
  parallel_slices(64, 2, [&](int64_t, int64_t, int64_t) {
    if (at::get_num_threads() == 1) ++serial;
  });
  EXPECT_EQ(serial.load(), 2);
  EXPECT_EQ(at::get_num_threads(), 2);
  at::set_num_threads(before);
}

TEST(CpuParallel, SerialIntraOpHoldsTheCallerAndKeepsTheSplit) {
  if (!dlsym(RTLD_DEFAULT, "omp_set_num_threads")) GTEST_SKIP() << "LibTorch without OpenMP in this build";
  const int before = at::get_num_threads();
  at::set_num_threads(2);
  // OpenBLAS held to one thread, so that LibTorch's count alone makes the budget of 2.
  const SingleThreadedBlas single_blas;
  const int64_t budget = cpu_thread_budget();
  ASSERT_EQ(budget, 2);
  {
    const SerialIntraOp serial;
    EXPECT_EQ(at::get_num_threads(), 1);
    // The held count still counts: a ray split inside the scope keeps its workers.
    EXPECT_EQ(cpu_thread_budget(), budget);
    if (blas_thread_control_available()) EXPECT_EQ(cpu_workers(1 << 20, 8), budget);
    {
      const SerialIntraOp nested;
      EXPECT_EQ(at::get_num_threads(), 1);
      EXPECT_EQ(cpu_thread_budget(), budget);
    }
    EXPECT_EQ(cpu_thread_budget(), budget);
  }
  EXPECT_EQ(at::get_num_threads(), 2);
  at::set_num_threads(before);
}

TEST(CpuParallel, WorkerCountFollowsTheBudgetAndTheMinimum) {
  EXPECT_EQ(cpu_workers(0, 8), 1);
  EXPECT_EQ(cpu_workers(15, 8), 1);  // two workers would get fewer than 8 each
  if (blas_thread_control_available()) {
    EXPECT_EQ(cpu_workers(1 << 20, 8), cpu_thread_budget());
  } else {
    EXPECT_EQ(cpu_workers(1 << 20, 8), 1);
  }
}

// 1e-20 x 1e-20 = 1e-40, a subnormal; with the flush both the product and a subnormal operand
// (1e-40 x 1) read as zero. volatile: computed at run time, under the thread's mode.
bool product_flushed() {
  volatile float a = 1e-20f, b = 1e-20f, one = 1.0f;
  volatile float tiny = a * b;
  volatile float through = 1e-40f * one;
  return tiny == 0.0f && through == 0.0f;
}

TEST(CpuParallel, SubnormalsFlushOnTheCallerAndInThreadsStartedAfter) {
  struct Restore {
    ~Restore() { at::globalContext().setFlushDenormal(false); }
  } restore;
  EXPECT_FALSE(product_flushed());  // the IEEE default: 1e-40 is representable
  if (!flush_subnormals()) GTEST_SKIP() << "this CPU has no flush-to-zero mode";
  EXPECT_TRUE(product_flushed());
  // LibTorch's own element-wise loop on the calling thread.
  const auto t = torch::full({64}, 1e-20f) * torch::full({64}, 1e-20f);
  EXPECT_EQ(t.count_nonzero().item<int64_t>(), 0);
  bool in_thread = false;
  std::thread([&] { in_thread = product_flushed(); }).join();
  EXPECT_TRUE(in_thread);
  std::vector<int> in_slices(2, 0);
  parallel_slices(2, 2, [&](int64_t w, int64_t, int64_t) { in_slices[static_cast<size_t>(w)] = product_flushed(); });
  EXPECT_EQ(in_slices, (std::vector<int>{1, 1}));
  at::globalContext().setFlushDenormal(false);
  EXPECT_FALSE(product_flushed());
  // The slices' threads are kept between calls: they take the caller's mode at every call.
  parallel_slices(2, 2, [&](int64_t w, int64_t, int64_t) { in_slices[static_cast<size_t>(w)] = product_flushed(); });
  EXPECT_EQ(in_slices, (std::vector<int>{0, 0}));
}

// Two threads splitting at the same time (a viewer's render beside training): each call covers its
// own range once, whichever of them gets the kept threads; repeated, so that each path is taken.
TEST(CpuParallel, ConcurrentCallersEachCoverTheirRange) {
  constexpr int kCalls = 200;
  std::vector<std::vector<int64_t>> sums(2, std::vector<int64_t>(kCalls, 0));
  const auto caller = [&](int c) {
    for (int i = 0; i < kCalls; ++i) {
      std::atomic<int64_t> total{0};
      parallel_slices(100 + i, 2, [&](int64_t, int64_t lo, int64_t hi) {
        int64_t s = 0;
        for (int64_t j = lo; j < hi; ++j) s += j;
        total += s;
      });
      sums[static_cast<size_t>(c)][static_cast<size_t>(i)] = total.load();
    }
  };
  std::thread other(caller, 1);
  caller(0);
  other.join();
  for (int c = 0; c < 2; ++c)
    for (int i = 0; i < kCalls; ++i) {
      const int64_t n = 100 + i;
      EXPECT_EQ(sums[static_cast<size_t>(c)][static_cast<size_t>(i)], n * (n - 1) / 2)
          << "caller " << c << " call " << i;
    }
}

}  // namespace
}  // namespace ablenerf
