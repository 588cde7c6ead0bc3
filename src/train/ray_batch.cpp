#include "train/ray_batch.h"

#include <algorithm>
#include <cmath>

namespace ablenerf {

RaySampler::RaySampler(const Split& split, const Intrinsics& k, const torch::Device& device, uint64_t seed,
                       std::optional<ErrorMapOptions> error_map, int64_t coarse_factor)
    : k_(k), gen_(at::detail::createCPUGenerator(seed)) {
  images_ = split.images.reshape({-1, 3}).to(device);
  c2w_ = split.c2w.to(device);
  pixels_ = images_.size(0);
  const auto n = static_cast<size_t>(split.c2w.size(0));
  cams_ = CameraTable::of(split.cameras.size() == n ? split.cameras : std::vector<Intrinsics>(n, k), device);
  if (error_map) {
    map_.emplace(split.c2w.size(0), k.height, k.width, *error_map, split.mask);
  } else if (split.mask.defined()) {
    kept_.emplace(split.c2w.size(0), k.height, k.width, ErrorMapOptions{4, 1.0}, split.mask);
  }
  const int64_t f = coarse_factor, count = split.c2w.size(0), h = f > 1 ? k.height / f : 0, w = f > 1 ? k.width / f : 0;
  if (h > 0 && w > 0) {
    // The blocks that fit, each averaged; with a mask, the blocks whose every pixel is kept.
    const auto blocks = [&](const torch::Tensor& t) {
      return t.slice(1, 0, h * f).slice(2, 0, w * f).reshape({count, h, f, w, f, -1});
    };
    const auto reduced = blocks(split.images).mean({2, 4});
    torch::Tensor keep;
    if (split.mask.defined()) keep = blocks(split.mask.unsqueeze(-1)).to(torch::kFloat).amin({2, 4, 5}) > 0.5;
    if (!keep.defined() || keep.any().item<bool>()) {
      coarse_factor_ = f, coarse_h_ = h, coarse_w_ = w, coarse_pixels_ = count * h * w;
      coarse_images_ = reduced.reshape({-1, 3}).contiguous().to(device);
      coarse_.emplace(count, h, w, ErrorMapOptions{4, 1.0}, keep);
    }
  }
}

torch::Tensor RaySampler::draw(int64_t global_size, int64_t coarse) {
  coarse = coarse_ ? std::clamp<int64_t>(coarse, 0, global_size) : 0;
  const int64_t full = global_size - coarse;
  torch::Tensor idx;
  if (map_)
    idx = map_->draw(full, gen_);
  else if (kept_)
    idx = kept_->draw(full, gen_);
  else
    idx = torch::randint(pixels_, {full}, gen_, torch::TensorOptions().dtype(torch::kLong));
  if (coarse == 0) return idx;
  return torch::cat({coarse_->draw(coarse, gen_) + pixels_, idx});
}

RaySampler::CoarsePixel RaySampler::split_coarse(const torch::Tensor& coarse_idx) const {
  const int64_t per_coarse = coarse_h_ * coarse_w_;
  const auto image = coarse_idx.div(per_coarse, "floor");
  const auto pix = coarse_idx - image * per_coarse;
  const auto row = pix.div(coarse_w_, "floor");
  return {image, row, pix - row * coarse_w_};
}

RayBatch RaySampler::gather(const torch::Tensor& flat_indices) const {
  auto idx = flat_indices.to(images_.device());
  const int64_t per_image = static_cast<int64_t>(k_.width) * k_.height;
  if (coarse_factor_ == 0) {
    auto image = idx.div(per_image, "floor");
    auto pix = idx - image * per_image;
    auto row = pix.div(k_.width, "floor");
    auto col = pix - row * k_.width;
    return {rays_for_pixels(c2w_.index_select(0, image), col, row, cams_.index(image)), images_.index_select(0, idx),
            image};
  }
  // Full and coarse pixels side by side, chosen per ray by tensor ops (no host synchronisation).
  const auto coarse = idx >= pixels_;
  const auto zero = torch::zeros_like(idx);
  const auto full_idx = torch::where(coarse, zero, idx);
  const auto coarse_idx = torch::where(coarse, idx - pixels_, zero);
  const CoarsePixel c = split_coarse(coarse_idx);
  const auto full_image = full_idx.div(per_image, "floor");
  const auto full_pix = full_idx - full_image * per_image;
  const auto full_row = full_pix.div(k_.width, "floor");
  const auto full_col = full_pix - full_row * k_.width;
  // A block's centre, in the full image's pixel indices (rays_for_pixels adds half a pixel).
  const double f = static_cast<double>(coarse_factor_), centre = (f - 1.0) / 2.0;
  const auto image = torch::where(coarse, c.image, full_image);
  const auto col = torch::where(coarse, c.col.to(torch::kDouble) * f + centre, full_col.to(torch::kDouble));
  const auto row = torch::where(coarse, c.row.to(torch::kDouble) * f + centre, full_row.to(torch::kDouble));
  Rays rays = rays_for_pixels(c2w_.index_select(0, image), col, row, cams_.index(image));
  rays.radii = rays.radii * (coarse.to(rays.radii.scalar_type()) * (f - 1.0) + 1.0).unsqueeze(1);
  const auto target =
      torch::where(coarse.unsqueeze(1), coarse_images_.index_select(0, coarse_idx), images_.index_select(0, full_idx));
  return {rays, target, image};
}

RayBatch RaySampler::next(int64_t global_size, int rank, int world) {
  auto idx = draw(global_size);
  const int64_t begin = global_size * rank / world, end = global_size * (rank + 1) / world;
  return gather(idx.slice(0, begin, end));
}

void RaySampler::observe(const torch::Tensor& flat_indices, const torch::Tensor& squared_error) {
  if (!map_) return;
  if (coarse_factor_ == 0) return map_->observe(flat_indices, squared_error);
  // A coarse pixel counts as its block's first pixel.
  const auto idx = flat_indices.to(torch::kCPU, torch::kLong);
  const CoarsePixel c = split_coarse((idx - pixels_).clamp_min(0));
  const auto first = c.image * (static_cast<int64_t>(k_.width) * k_.height) + c.row * coarse_factor_ * k_.width +
                     c.col * coarse_factor_;
  map_->observe(torch::where(idx >= pixels_, first, idx), squared_error);
}

int64_t coarse_pixel_rays(int64_t rays, double share, double until, double fraction) {
  if (!(share > 0) || !(until > 0)) return 0;
  const double left = share * std::max(0.0, 1.0 - fraction / until);
  return std::clamp<int64_t>(std::llround(left * static_cast<double>(rays)), 0, rays);
}

torch::Tensor RaySampler::rng_state() const { return gen_.get_state(); }
void RaySampler::set_rng_state(const torch::Tensor& state) { gen_.set_state(state); }
torch::Tensor RaySampler::map_state() const { return map_ ? map_->state() : torch::Tensor(); }
void RaySampler::set_map_state(const torch::Tensor& state) {
  if (map_ && state.defined()) map_->set_state(state);
}

}  // namespace ablenerf
