#pragma once
// Ray-parallel CPU execution: a batch of rays is cut into contiguous slices, one per CPU
// thread, and each thread runs its slice with single-threaded BLAS.
//
// Why: on a few cores, LibTorch (one intra-op thread by default here) runs every element-wise op
// on one core while OpenBLAS's own pool synchronises inside each product. Rays are independent
// through the whole model, so running whole slices side by side keeps every core busy in every
// op and lets each product run without synchronisation. The mathematics are unchanged; only the
// summation order inside products may differ.
#include <torch/torch.h>

#include <functional>
#include <string>
#include <utility>
#include <vector>

namespace ablenerf {

// Threads the user allows for CPU work: LibTorch's intra-op count or OpenBLAS's (which follows
// OPENBLAS_NUM_THREADS / OMP_NUM_THREADS), whichever is larger.
int64_t cpu_thread_budget();

// Workers for n items when each should get at least min_per_worker: in [1, cpu_thread_budget()];
// always 1 inside a worker of parallel_slices (no nesting) or without OpenBLAS's thread control.
int64_t cpu_workers(int64_t n, int64_t min_per_worker);

// Workers for a batch of `rays` rays split across CPU threads: the one rule for every ray split
// (rendering forward and training slices); each worker gets at least a handful of rays, below which
// thread start-up dominates.
int64_t ray_workers(int64_t rays);

// True when OpenBLAS's thread control was found (other BLAS builds: always run serially).
bool blas_thread_control_available();

// Single-threaded BLAS for the scope (restores the previous count; nothing without OpenBLAS's
// thread control). OpenBLAS's count is process-wide: take it on the thread that starts the work
// (parallel_slices does); inside a worker the count is already one and the scope changes nothing.
class SingleThreadedBlas {
 public:
  SingleThreadedBlas();
  ~SingleThreadedBlas();
  SingleThreadedBlas(const SingleThreadedBlas&) = delete;
  SingleThreadedBlas& operator=(const SingleThreadedBlas&) = delete;

 private:
  int previous_ = 0;
};

// LibTorch's intra-op loops on the calling thread run serially for the scope (its OpenMP team size
// set to 1, restored after; nothing where OpenMP's control is absent). For a thread that runs
// parallel_slices again and again (a CPU training step): between the splits its own table-sized ops
// would open a team whose idle member spins on a core into the next split's slices. The count it
// held still counts in cpu_thread_budget() on that thread.
class SerialIntraOp {
 public:
  SerialIntraOp();
  ~SerialIntraOp();
  SerialIntraOp(const SerialIntraOp&) = delete;
  SerialIntraOp& operator=(const SerialIntraOp&) = delete;

 private:
  int previous_ = 0;
  int held_ = 0;
};

// Subnormal floats (magnitudes below 1.2e-38) flushed to zero in CPU arithmetic, as inputs and as
// results, on the calling thread and every thread it starts afterwards (a new thread inherits its
// creator's floating-point environment; parallel_slices's slices take their caller's). Call it
// first thing in a program. Why: a capture-preset run drifts values into that range (the table's
// weight decay shrinks rows no ray reads, Adam's second moments of rarely touched rows decay with
// them), every operation on one costs tens of times a normal one, and the training step slowed to a
// third of its speed after its first ~2,000 steps (docs/benchmarks/history.md, "Subnormal floats").
// Nothing the model renders or learns from lies in that range. False where the CPU has no such
// mode.
bool flush_subnormals();

// OpenBLAS's name for the kernels it chose for this CPU (openblas_get_corename), or "" without
// OpenBLAS's runtime dispatch.
std::string blas_core_name();

// The OPENBLAS_CORETYPE this process should have been started with, or "" when OpenBLAS's own choice
// stands: OpenBLAS 0.3.21 (Debian bookworm's) does not know CPUs newer than its release (Sapphire
// Rapids among them) and falls back to its Prescott kernels (SSE3, no FMA) on them, 12% of a
// capture-preset training step's time in a profile on such a 2-core machine. Where it chose Prescott
// on a CPU with AVX2 and FMA, and the variable is unset: "SkylakeX" with AVX-512 (F, DQ, BW, VL),
// else "Haswell" (docs/benchmarks/history.md, "OpenBLAS's kernels"). OpenBLAS reads the variable once, when
// it is loaded, so the program restarts itself with it (cli/main.cpp).
std::string blas_core_override();

// Runs fn(w, lo, hi) for the W contiguous slices [lo, hi) of [0, n), one thread each (the calling
// thread takes slice 0, the others threads kept from call to call), with single-threaded BLAS for
// the duration. Each worker takes the caller's grad mode, inference mode and floating-point
// environment. The first exception thrown by any slice is rethrown after every thread has
// finished. W == 1 calls fn(0, 0, n) directly, BLAS untouched. Safe to call from several threads
// at once (one of them gets the kept threads, the others start their own for the call).
void parallel_slices(int64_t n, int64_t workers, const std::function<void(int64_t w, int64_t lo, int64_t hi)>& fn);

// A set of indices as half-open ranges [begin, end), sorted and disjoint (e.g. the entries of a grid
// table that lookups can reach: kernels/hash_grid_shape.h).
using IndexRanges = std::vector<std::pair<int64_t, int64_t>>;
int64_t index_count(const IndexRanges& ranges);

// parallel_slices over the indices of `ranges` as one run: worker w gets about 1/W of them, as
// fn(w, lo, hi) once for each range its share meets (every [lo, hi) inside one range, in order).
void parallel_ranges(const IndexRanges& ranges, int64_t workers,
                     const std::function<void(int64_t w, int64_t lo, int64_t hi)>& fn);

}  // namespace ablenerf
