#include "kernels/hash_grid.h"

#include <ATen/record_function.h>
#include <cmath>
#include <stdexcept>
#include <string>

#include "kernels/hash_grid_cpu.h"
#include "kernels/table_gradient.h"
#include "kernels/tensor_checks.h"

#ifdef ABLENERF_CUDA_KERNELS
#include <ATen/cuda/CUDAContext.h>
#include <c10/cuda/CUDAGuard.h>

#include "kernels/hash_grid_launch.h"
#endif

namespace ablenerf {

namespace {

constexpr const char* kOp = "hash_grid_encode";

void need(bool ok, const std::string& what) {
  if (!ok) throw std::invalid_argument("hash grid: " + what);
}

void check_inputs(const torch::Tensor& positions, const torch::Tensor& table, const HashGridShape& s) {
  namespace check = kernel_checks;
  TORCH_CHECK(positions.defined() && table.defined(), kOp, ": positions and table must be defined");
  TORCH_CHECK(positions.dim() == 2 && positions.size(1) == 3, kOp, ": positions must be (N, 3), got ",
              positions.sizes());
  TORCH_CHECK(
      table.dim() == 3 && table.size(0) == s.levels && table.size(1) == s.table_size && table.size(2) == s.features,
      kOp, ": table must be (", s.levels, ", ", s.table_size, ", ", s.features, "), got ", table.sizes());
  TORCH_CHECK(s.features <= kHashGridMaxFeatures, kOp, ": at most ", kHashGridMaxFeatures, " features per level");
  check::dtype(kOp, "positions", positions, torch::kFloat);
  check::dtype(kOp, "table", table, torch::kFloat);
  check::contiguous(kOp, "positions", positions);
  check::contiguous(kOp, "table", table);
  TORCH_CHECK(table.device() == positions.device(), kOp, ": table must be on ", positions.device(),
              " like positions, got ", table.device());
  TORCH_CHECK(positions.is_cpu() || positions.is_cuda(), kOp, ": positions must be on the CPU or a CUDA device");
}

std::vector<int64_t> resolutions(const HashGridShape& s) { return {s.resolution, s.resolution + s.levels}; }

HashGridShape shape_of(const torch::Tensor& table, const std::vector<int64_t>& res) {
  HashGridShape s;
  s.levels = static_cast<int>(table.size(0));
  s.table_size = table.size(1);
  s.features = static_cast<int>(table.size(2));
  for (int l = 0; l < s.levels; ++l) s.resolution[l] = static_cast<int>(res[static_cast<size_t>(l)]);
  return s;
}

// Saved for backward: the positions (the rows and weights are recomputed) and the resolutions; with
// a TableGradient key (kernels/table_gradient.h) the sink and the key: the table's scatter is then
// deferred to the sink and autograd gets no gradient for the table (the table stays an input so that the node exists
// when nothing else needs a gradient).
class HashGridFunction : public torch::autograd::Function<HashGridFunction> {
 public:
  // `scales`: a contiguous CPU tensor (n, levels) that takes no gradient, or undefined; kept in the
  // node's data rather than as an input, having no gradient.
  static torch::Tensor forward(torch::autograd::AutogradContext* ctx, const torch::Tensor& positions,
                               const torch::Tensor& table, const std::vector<int64_t>& res, TableGradient* sink,
                               int64_t key, const torch::Tensor* scales_in) {
    const torch::Tensor& scales = *scales_in;
    const HashGridShape s = shape_of(table, res);
    const int64_t n = positions.size(0);
    auto out = torch::empty({n, s.levels, s.features}, table.options());
    if (positions.is_cpu()) {
      hash_grid_forward_cpu(positions.data_ptr<float>(), n, table.data_ptr<float>(), s, scale_data(scales),
                            out.data_ptr<float>());
    } else {
#ifdef ABLENERF_CUDA_KERNELS
      const c10::cuda::CUDAGuard device(positions.device());
      C10_CUDA_CHECK(launch_hash_grid_forward(positions.data_ptr<float>(), n, table.data_ptr<float>(), s,
                                              out.data_ptr<float>(), at::cuda::getCurrentCUDAStream()));
#else
      TORCH_CHECK(false, kOp, ": built without CUDA kernels");
#endif
    }
    ctx->save_for_backward({positions, table});
    if (scales.defined()) ctx->saved_data["scales"] = scales;
    ctx->saved_data["res"] = res;
    // The sink outlives the graph: it belongs to the module that owns the table.
    ctx->saved_data["sink"] = static_cast<int64_t>(reinterpret_cast<intptr_t>(sink));
    ctx->saved_data["key"] = key;
    return out;
  }

  static torch::autograd::variable_list backward(torch::autograd::AutogradContext* ctx,
                                                 torch::autograd::variable_list grads) {
    const auto saved = ctx->get_saved_variables();
    const auto &positions = saved[0], &table = saved[1];
    const torch::Tensor scale_tensor =
        ctx->saved_data.count("scales") != 0 ? ctx->saved_data["scales"].toTensor() : torch::Tensor();
    const float* scales = scale_data(scale_tensor);
    const HashGridShape s = shape_of(table, ctx->saved_data["res"].toIntVector());
    const auto g = grads[0].to(torch::kFloat).contiguous();
    const int64_t n = positions.size(0);
    torch::Tensor grad_positions, grad_table;
    // The positions' gradient only where something upstream asks for it (camera refinement); the
    // table's whenever the table trains.
    if (ctx->needs_input_grad(0)) grad_positions = torch::empty_like(positions);
    auto* sink = reinterpret_cast<TableGradient*>(static_cast<intptr_t>(ctx->saved_data["sink"].toInt()));
    if (ctx->needs_input_grad(1) && sink == nullptr) grad_table = torch::zeros_like(table);
    if (positions.is_cpu()) {
      if (sink != nullptr && ctx->needs_input_grad(1))
        sink->defer(static_cast<int>(ctx->saved_data["key"].toInt()), {positions, g, scale_tensor});
      if (grad_table.defined())
        hash_grid_backward_cpu(positions.data_ptr<float>(), n, g.data_ptr<float>(), s, scales,
                               grad_table.data_ptr<float>());
      if (grad_positions.defined())
        hash_grid_backward_positions_cpu(positions.data_ptr<float>(), n, g.data_ptr<float>(), table.data_ptr<float>(),
                                         s, scales, grad_positions.data_ptr<float>());
    } else {
#ifdef ABLENERF_CUDA_KERNELS
      const c10::cuda::CUDAGuard device(positions.device());
      const auto stream = at::cuda::getCurrentCUDAStream();
      if (grad_table.defined())
        C10_CUDA_CHECK(launch_hash_grid_backward(positions.data_ptr<float>(), n, g.data_ptr<float>(), s,
                                                 grad_table.data_ptr<float>(), stream));
      if (grad_positions.defined())
        C10_CUDA_CHECK(launch_hash_grid_backward_positions(positions.data_ptr<float>(), n, g.data_ptr<float>(),
                                                           table.data_ptr<float>(), s, grad_positions.data_ptr<float>(),
                                                           stream));
#endif
    }
    return {grad_positions, grad_table, torch::Tensor(), torch::Tensor(), torch::Tensor(), torch::Tensor()};
  }

 private:
  static const float* scale_data(const torch::Tensor& scales) {
    return scales.defined() ? scales.data_ptr<float>() : nullptr;
  }
};

}  // namespace

HashGridShape hash_grid_shape(int levels, int features, int log2_table, int base_resolution, int max_resolution) {
  need(levels >= 1 && levels <= kHashGridMaxLevels, "levels must be in 1.." + std::to_string(kHashGridMaxLevels));
  need(features >= 1 && features <= kHashGridMaxFeatures,
       "features must be in 1.." + std::to_string(kHashGridMaxFeatures));
  need(log2_table >= 1 && log2_table <= 24, "log2 of the table size must be in 1..24");
  need(base_resolution >= 1 && max_resolution >= base_resolution, "resolutions must satisfy 1 <= base <= max");
  HashGridShape s;
  s.levels = levels;
  s.features = features;
  s.table_size = int64_t{1} << log2_table;
  const double growth =
      levels > 1 ? std::exp((std::log(double(max_resolution)) - std::log(double(base_resolution))) / (levels - 1))
                 : 1.0;
  for (int l = 0; l < levels; ++l)
    // The small tolerance keeps a level that lands on an integer (e.g. 16 * 2^l) from flooring below it.
    s.resolution[l] = static_cast<int>(std::floor(base_resolution * std::pow(growth, l) + 1e-9));
  return s;
}

torch::Tensor hash_grid_encode(const torch::Tensor& positions, const torch::Tensor& table, const HashGridShape& shape,
                               TableGradient* gradient, const torch::Tensor& scales) {
  RECORD_FUNCTION("ablenerf::hash_grid", std::vector<c10::IValue>());
  check_inputs(positions, table, shape);
  if (scales.defined()) {
    namespace check = kernel_checks;
    TORCH_CHECK(scales.dim() == 2 && scales.size(0) == positions.size(0) && scales.size(1) == shape.levels, kOp,
                ": scales must be (", positions.size(0), ", ", shape.levels, "), got ", scales.sizes());
    check::dtype(kOp, "scales", scales, torch::kFloat);
    TORCH_CHECK(scales.device() == positions.device(), kOp, ": scales must be on ", positions.device(),
                " like positions, got ", scales.device());
  }
  const int key = TableGradient::current_key();
  const bool deferred =
      gradient != nullptr && key >= 0 && positions.is_cpu() && table.requires_grad() && torch::GradMode::is_enabled();
  // The CPU loops multiply by the scales themselves; scales that take a gradient, and the CUDA
  // kernels, get a separate product.
  const bool fused_scales = scales.defined() && positions.is_cpu() && !scales.requires_grad();
  const torch::Tensor loop_scales = fused_scales ? scales.contiguous() : torch::Tensor();
  const auto out = HashGridFunction::apply(positions, table, resolutions(shape), deferred ? gradient : nullptr,
                                           int64_t{deferred ? key : -1}, &loop_scales);
  return scales.defined() && !fused_scales ? out * scales.unsqueeze(-1) : out;
}

IndexRanges hash_grid_table_entries(const HashGridShape& shape) {
  IndexRanges out;
  const int64_t f = shape.features;
  for (int level = 0; level < shape.levels; ++level) {
    const int64_t begin = level * shape.table_size * f, end = begin + hash_grid_level_rows(shape, level) * f;
    if (!out.empty() && out.back().second == begin)
      out.back().second = end;  // joined to the level before (hashed levels fill their rows)
    else
      out.emplace_back(begin, end);
  }
  return out;
}

torch::Tensor hash_grid_rows_reference(const torch::Tensor& x, const torch::Tensor& y, const torch::Tensor& z,
                                       const HashGridShape& s, int level) {
  const int64_t side = int64_t{s.resolution[level]} + 1;
  if (side * side * side <= s.table_size) return x + side * (y + side * z);
  // Coordinates below 2^24 keep the int64 products exact; their low 32 bits are the uint32 products'.
  const auto h = torch::bitwise_xor(torch::bitwise_xor(x, y * int64_t{kHashPrimeY}), z * int64_t{kHashPrimeZ});
  return torch::bitwise_and(h, s.table_size - 1);
}

torch::Tensor hash_grid_encode_reference(const torch::Tensor& positions, const torch::Tensor& table,
                                         const HashGridShape& s) {
  TORCH_CHECK(positions.dim() == 2 && positions.size(1) == 3, "hash_grid_encode_reference: positions must be (N, 3)");
  TORCH_CHECK(
      table.dim() == 3 && table.size(0) == s.levels && table.size(1) == s.table_size && table.size(2) == s.features,
      "hash_grid_encode_reference: table must be (levels, table_size, features), got ", table.sizes());
  // As the kernels: NaN -> 0, clamped to [0, 1], cell and fraction in float32.
  const auto p = torch::nan_to_num(positions.to(torch::kFloat), 0.0).clamp(0, 1);
  std::vector<torch::Tensor> out;
  for (int l = 0; l < s.levels; ++l) {
    const double res = s.resolution[l];
    const auto q = p * res;
    const auto cell = q.floor().clamp_max(res - 1);
    const auto frac = (q - cell).to(table.scalar_type());
    const auto c = cell.to(torch::kLong);
    const auto level_rows = table.select(0, l);
    torch::Tensor acc;
    for (int k = 0; k < 8; ++k) {
      torch::Tensor v[3], w;
      for (int d = 0; d < 3; ++d) {
        const int bit = (k >> d) & 1;
        v[d] = c.select(1, d) + bit;
        const auto wd = bit ? frac.select(1, d) : 1 - frac.select(1, d);
        w = d == 0 ? wd : w * wd;
      }
      const auto term = w.unsqueeze(1) * level_rows.index_select(0, hash_grid_rows_reference(v[0], v[1], v[2], s, l));
      acc = k == 0 ? term : acc + term;
    }
    out.push_back(acc);
  }
  return torch::stack(out, 1);
}

}  // namespace ablenerf
