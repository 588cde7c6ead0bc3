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
  const auto n = static_cast<size_t>(count);
  build_lens_table(split.cameras.size() == n ? split.cameras : std::vector<Intrinsics>(n, k), device);
}

namespace {

bool same_camera(const Intrinsics& a, const Intrinsics& b) {
  return a.fx == b.fx && a.fy == b.fy && a.cx == b.cx && a.cy == b.cy && a.model == b.model && a.dist == b.dist;
}

// Pixels per lens_coordinates call while the table is made: bounds its float64 temporaries.
constexpr int64_t kLensChunk = int64_t{1} << 18;

// Rows (col, row) of the points (col0 + i % w * step, row0 + i / w * step), i < h * w, through
// `camera`: x, y, radius x radius_scale, float32, (h * w, 3).
torch::Tensor lens_block(const Intrinsics& camera, int64_t h, int64_t w, double step, double offset,
                         double radius_scale) {
  auto out = torch::empty({h * w, 3}, torch::kFloat);
  const CameraTable one = CameraTable::of({camera});
  for (int64_t lo = 0; lo < h * w; lo += kLensChunk) {
    const int64_t hi = std::min(h * w, lo + kLensChunk);
    const auto i = torch::arange(lo, hi, torch::kLong);
    const auto col = i.remainder(w).to(torch::kDouble) * step + offset;
    const auto row = i.div(w, "floor").to(torch::kDouble) * step + offset;
    const LensCoordinates c = lens_coordinates(col, row, one.repeat_first(hi - lo));
    out.slice(0, lo, hi).copy_(torch::stack({c.x, c.y, c.radii.squeeze(1) * radius_scale}, 1));
  }
  return out;
}

}  // namespace

void RaySampler::build_lens_table(const std::vector<Intrinsics>& cameras, const torch::Device& device) {
  std::vector<Intrinsics> distinct;
  std::vector<int64_t> camera_of;
  for (const Intrinsics& c : cameras) {
    auto it = std::find_if(distinct.begin(), distinct.end(), [&](const Intrinsics& d) { return same_camera(c, d); });
    camera_of.push_back(it - distinct.begin());
    if (it == distinct.end()) distinct.push_back(c);
  }
  const int64_t full = int64_t{k_.height} * k_.width, coarse = coarse_factor_ ? coarse_h_ * coarse_w_ : 0;
  std::vector<torch::Tensor> blocks;
  const double f = static_cast<double>(coarse_factor_);
  for (const Intrinsics& c : distinct) {
    blocks.push_back(lens_block(c, k_.height, k_.width, 1.0, 0.0, 1.0));
    // A block's centre, in the full image's pixel indices (lens_coordinates adds half a pixel); its
    // cone f times wider.
    if (coarse > 0) blocks.push_back(lens_block(c, coarse_h_, coarse_w_, f, (f - 1.0) / 2.0, f));
  }
  lens_ = torch::cat(blocks).to(device);
  std::vector<int64_t> start;
  for (const int64_t c : camera_of) start.push_back(c * (full + coarse));
  lens_start_ = torch::tensor(start, torch::kLong).to(device);
}

torch::Tensor RaySampler::full_lens_rows(const torch::Tensor& image, const torch::Tensor& pixel) const {
  return lens_start_.index_select(0, image) + pixel;
}

torch::Tensor RaySampler::coarse_lens_rows(const CoarsePixel& c) const {
  // The coarse block follows the camera's H*W full pixels.
  return lens_start_.index_select(0, c.image) + int64_t{k_.height} * k_.width + c.row * coarse_w_ + c.col;
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

Rays RaySampler::rays_from(const torch::Tensor& image, const torch::Tensor& lens_rows) const {
  const auto l = lens_.index_select(0, lens_rows);
  return rays_from_lens_coordinates(c2w_.index_select(0, image), {l.select(1, 0), l.select(1, 1), l.slice(1, 2, 3)});
}

RayBatch RaySampler::gather(const torch::Tensor& flat_indices) const {
  auto idx = flat_indices.to(images_.device());
  const int64_t per_image = static_cast<int64_t>(k_.width) * k_.height;
  if (coarse_factor_ == 0) {
    auto image = idx.div(per_image, "floor");
    auto pix = idx - image * per_image;
    return {rays_from(image, full_lens_rows(image, pix)), images_.index_select(0, idx), image};
  }
  // Full and coarse pixels side by side, chosen per ray by tensor ops (no host synchronisation).
  const auto coarse = idx >= pixels_;
  const auto zero = torch::zeros_like(idx);
  const auto full_idx = torch::where(coarse, zero, idx);
  const auto coarse_idx = torch::where(coarse, idx - pixels_, zero);
  const CoarsePixel c = split_coarse(coarse_idx);
  const auto full_image = full_idx.div(per_image, "floor");
  const auto full_pix = full_idx - full_image * per_image;
  const auto image = torch::where(coarse, c.image, full_image);
  const Rays rays = rays_from(image, torch::where(coarse, coarse_lens_rows(c), full_lens_rows(full_image, full_pix)));
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
