#include "train/ray_batch.h"

namespace ablenerf {

RaySampler::RaySampler(const Split& split, const Intrinsics& k, const torch::Device& device, uint64_t seed,
                       std::optional<ErrorMapOptions> error_map)
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
}

torch::Tensor RaySampler::draw(int64_t global_size) {
  if (map_) return map_->draw(global_size, gen_);
  if (kept_) return kept_->draw(global_size, gen_);
  return torch::randint(pixels_, {global_size}, gen_, torch::TensorOptions().dtype(torch::kLong));
}

RayBatch RaySampler::gather(const torch::Tensor& flat_indices) const {
  auto idx = flat_indices.to(images_.device());
  const int64_t per_image = static_cast<int64_t>(k_.width) * k_.height;
  auto image = idx.div(per_image, "floor");
  auto pix = idx - image * per_image;
  auto row = pix.div(k_.width, "floor");
  auto col = pix - row * k_.width;
  return {rays_for_pixels(c2w_.index_select(0, image), col, row, cams_.index(image)), images_.index_select(0, idx),
          image};
}

RayBatch RaySampler::next(int64_t global_size, int rank, int world) {
  auto idx = draw(global_size);
  const int64_t begin = global_size * rank / world, end = global_size * (rank + 1) / world;
  return gather(idx.slice(0, begin, end));
}

void RaySampler::observe(const torch::Tensor& flat_indices, const torch::Tensor& squared_error) {
  if (map_) map_->observe(flat_indices, squared_error);
}

torch::Tensor RaySampler::rng_state() const { return gen_.get_state(); }
void RaySampler::set_rng_state(const torch::Tensor& state) { gen_.set_state(state); }
torch::Tensor RaySampler::map_state() const { return map_ ? map_->state() : torch::Tensor(); }
void RaySampler::set_map_state(const torch::Tensor& state) {
  if (map_ && state.defined()) map_->set_state(state);
}

}  // namespace ablenerf
