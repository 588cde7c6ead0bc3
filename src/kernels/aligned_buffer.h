#pragma once
// A buffer of T that starts on a cache line (64 bytes), for operands the CPU kernels read in
// vectors or tiles: from a std::vector (16-byte aligned) three 64-byte loads in four cross two
// lines. With the transposed weights of linear_cpu in one, the paper's model rendered 1.25x faster
// (docs/benchmarks/history.md, "The grid tables' gradient formed inside Adam's update"); AMX's
// tile loads and the packed bfloat16 operands (kernels/bf16_gemm.h) use it likewise.
#include <cstddef>
#include <cstdlib>
#include <memory>
#include <new>

namespace ablenerf {

template <class T>
class AlignedBuffer {
 public:
  explicit AlignedBuffer(size_t n = 0) { resize(n); }
  // At least n values (the contents are not kept when it grows).
  void resize(size_t n) {
    if (n <= capacity_) return;
    const size_t bytes = (n * sizeof(T) + 63) / 64 * 64;
    data_.reset(static_cast<T*>(std::aligned_alloc(64, bytes)));
    if (!data_) throw std::bad_alloc();
    capacity_ = bytes / sizeof(T);
  }
  T* data() const { return data_.get(); }

 private:
  struct Free {
    void operator()(T* p) const { std::free(p); }
  };
  std::unique_ptr<T, Free> data_;
  size_t capacity_ = 0;
};

using AlignedFloats = AlignedBuffer<float>;

}  // namespace ablenerf
