#include "train/error_map.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace ablenerf {

namespace {
// How far a tile's error moves towards a new observation.
constexpr double kErrorBlend = 0.5;
}  // namespace

ErrorMap::ErrorMap(int64_t images, int64_t height, int64_t width, ErrorMapOptions options, const torch::Tensor& keep)
    : images_(images), height_(height), width_(width), opt_(options) {
  if (images < 1 || height < 1 || width < 1) throw std::invalid_argument("ErrorMap: empty image set");
  if (opt_.tile < 1 || opt_.tile > 256) throw std::invalid_argument("ErrorMap: tile must be in [1, 256]");
  if (!(opt_.uniform_share >= 0 && opt_.uniform_share <= 1))
    throw std::invalid_argument("ErrorMap: uniform_share must be in [0, 1]");
  tiles_x_ = (width + opt_.tile - 1) / opt_.tile;
  tiles_y_ = (height + opt_.tile - 1) / opt_.tile;
  error_.assign(static_cast<size_t>(images * tiles_x_ * tiles_y_), 0.0);
  torch::Tensor k;
  if (keep.defined()) {
    if (keep.dim() != 3 || keep.size(0) != images || keep.size(1) != height || keep.size(2) != width)
      throw std::invalid_argument("ErrorMap: the mask must be (images, height, width)");
    k = keep.to(torch::kCPU, torch::kBool).contiguous();
    kept_start_.assign(error_.size() + 1, 0);
  }
  const bool* kp = k.defined() ? k.data_ptr<bool>() : nullptr;
  counts_.resize(error_.size());
  for (int64_t t = 0; t < tiles(); ++t) {
    const TileRect r = tile_rect(t);
    const auto slot = static_cast<size_t>(t);
    if (!kp) {
      counts_[slot] = static_cast<int32_t>(r.height * r.width);
      continue;
    }
    for (int64_t dr = 0; dr < r.height; ++dr)
      for (int64_t dc = 0; dc < r.width; ++dc)
        if (kp[(r.image * height_ + r.row + dr) * width_ + r.col + dc])
          kept_.push_back(static_cast<uint16_t>(dr * opt_.tile + dc));
    kept_start_[slot + 1] = static_cast<int64_t>(kept_.size());
    counts_[slot] = static_cast<int32_t>(kept_start_[slot + 1] - kept_start_[slot]);
  }
  if (kp && kept_.empty()) throw std::invalid_argument("ErrorMap: the mask keeps no pixel");
}

int64_t ErrorMap::kept_count(int64_t t) const { return counts_[static_cast<size_t>(t)]; }

ErrorMap::TileRect ErrorMap::tile_rect(int64_t t) const {
  const int64_t per_image = tiles_x_ * tiles_y_;
  const int64_t in_image = t % per_image;
  const int64_t row = in_image / tiles_x_ * opt_.tile, col = in_image % tiles_x_ * opt_.tile;
  return {t / per_image, row, col, std::min(opt_.tile, height_ - row), std::min(opt_.tile, width_ - col)};
}

int64_t ErrorMap::tile_of(int64_t pixel) const {
  const int64_t per_image = height_ * width_;
  const int64_t image = pixel / per_image, in_image = pixel % per_image;
  const int64_t row = in_image / width_, col = in_image % width_;
  return (image * tiles_y_ + row / opt_.tile) * tiles_x_ + col / opt_.tile;
}

template <class F>
void ErrorMap::each_probability(F&& f) const {
  const size_t n = error_.size();
  double sum = 0;
  for (size_t t = 0; t < n; ++t)
    if (counts_[t] > 0) sum += error_[t];
  const double pixels =
      static_cast<double>(kept_start_.empty() ? images_ * height_ * width_ : static_cast<int64_t>(kept_.size()));
  const bool by_error = seeded_ && sum > 0;
  const double share = by_error ? opt_.uniform_share : 1.0;
  const double per_pixel = share / pixels, per_error = by_error ? (1.0 - share) / sum : 0.0;
  for (size_t t = 0; t < n; ++t) f(t, counts_[t] > 0 ? per_pixel * counts_[t] + per_error * error_[t] : 0.0);
}

torch::Tensor ErrorMap::probabilities() const {
  auto p = torch::empty({tiles()}, torch::kDouble);
  double* out = p.data_ptr<double>();
  each_probability([&](size_t t, double prob) { out[t] = prob; });
  return p;
}

void ErrorMap::rebuild_cdf() {
  cdf_.resize(error_.size());
  double run = 0;
  each_probability([&](size_t t, double prob) { cdf_[t] = (run += prob); });
  dirty_ = false;
}

torch::Tensor ErrorMap::draw(int64_t n, torch::Generator& gen) {
  if (dirty_) rebuild_cdf();
  const auto u = torch::rand({n, 3}, gen, torch::kDouble);
  const auto ua = u.accessor<double, 2>();
  auto out = torch::empty({n}, torch::kLong);
  int64_t* idx = out.data_ptr<int64_t>();
  const double total = cdf_.back();
  // A uniform in [0, 1) to an offset in [0, size).
  const auto offset = [](double u, int64_t size) {
    return std::min<int64_t>(static_cast<int64_t>(u * static_cast<double>(size)), size - 1);
  };
  for (int64_t i = 0; i < n; ++i) {
    const auto it = std::upper_bound(cdf_.begin(), cdf_.end(), ua[i][0] * total);
    int64_t t = std::min<int64_t>(it - cdf_.begin(), tiles() - 1);
    if (!kept_start_.empty()) {
      // Rounding can land past the last drawable tile: step back to one that has kept pixels.
      while (kept_count(t) == 0 && t > 0) --t;
      while (kept_count(t) == 0) ++t;
    }
    const TileRect r = tile_rect(t);
    int64_t row, col;
    if (kept_start_.empty()) {
      row = r.row + offset(ua[i][1], r.height), col = r.col + offset(ua[i][2], r.width);
    } else {
      const int64_t at = kept_start_[static_cast<size_t>(t)] + offset(ua[i][1], kept_count(t));
      const int64_t in_tile = kept_[static_cast<size_t>(at)];
      row = r.row + in_tile / opt_.tile, col = r.col + in_tile % opt_.tile;
    }
    idx[i] = (r.image * height_ + row) * width_ + col;
  }
  return out;
}

void ErrorMap::observe(const torch::Tensor& pixels, const torch::Tensor& squared_error) {
  const auto px = pixels.to(torch::kCPU, torch::kLong).contiguous().reshape({-1});
  const auto se = squared_error.detach().to(torch::kCPU, torch::kDouble).contiguous().reshape({-1});
  if (px.size(0) != se.size(0)) throw std::invalid_argument("ErrorMap::observe: one error per pixel");
  const int64_t n = px.size(0);
  if (n == 0) return;
  const int64_t* p = px.data_ptr<int64_t>();
  const double* e = se.data_ptr<double>();
  if (!seeded_) {
    double sum = 0;
    int64_t finite = 0;
    for (int64_t i = 0; i < n; ++i)
      if (std::isfinite(e[i])) sum += e[i], ++finite;
    if (finite == 0) return;
    std::fill(error_.begin(), error_.end(), sum / static_cast<double>(finite));
    seeded_ = true;
  }
  const int64_t pixel_count = images_ * height_ * width_;
  for (int64_t i = 0; i < n; ++i) {
    if (p[i] < 0 || p[i] >= pixel_count) throw std::invalid_argument("ErrorMap::observe: pixel index out of range");
    if (!std::isfinite(e[i])) continue;  // a skipped (non-finite) step teaches nothing
    double& slot = error_[static_cast<size_t>(tile_of(p[i]))];
    slot += kErrorBlend * (e[i] - slot);
  }
  dirty_ = true;
}

torch::Tensor ErrorMap::state() const {
  auto s = torch::empty({tiles() + 1}, torch::kDouble);
  double* d = s.data_ptr<double>();
  d[0] = seeded_ ? 1.0 : 0.0;
  std::copy(error_.begin(), error_.end(), d + 1);
  return s;
}

void ErrorMap::set_state(const torch::Tensor& state) {
  const auto s = state.to(torch::kCPU, torch::kDouble).contiguous().reshape({-1});
  if (s.size(0) != tiles() + 1) throw std::invalid_argument("ErrorMap::set_state: the map has another size");
  const double* d = s.data_ptr<double>();
  seeded_ = d[0] != 0.0;
  std::copy(d + 1, d + 1 + tiles(), error_.begin());
  dirty_ = true;
}

}  // namespace ablenerf
