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
  rebuild_tree();
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

int64_t ErrorMap::drawable_pixels() const {
  return kept_start_.empty() ? images_ * height_ * width_ : static_cast<int64_t>(kept_.size());
}

int64_t ErrorMap::fixed_error(size_t t) const {
  if (counts_[t] == 0) return 0;
  const double e = std::clamp(error_[t], 0.0, kMaxTileError);
  return static_cast<int64_t>(std::llround(e * kFixedScale));
}

void ErrorMap::rebuild_tree() {
  const size_t n = error_.size();
  fixed_.resize(n);
  tree_.assign(n, 0);
  fixed_total_ = 0;
  for (size_t t = 0; t < n; ++t) {
    fixed_[t] = fixed_error(t);
    fixed_total_ += fixed_[t];
    tree_[t] += fixed_[t];
    // Node i (1-based, here t + 1) passes its sum to its parent i + lowbit(i).
    const size_t i = t + 1, parent = i + (i & (~i + 1));
    if (parent <= n) tree_[parent - 1] += tree_[t];
  }
}

void ErrorMap::add_to_tree(size_t t, int64_t d) {
  fixed_total_ += d;
  for (size_t i = t + 1; i <= tree_.size(); i += i & (~i + 1)) tree_[i - 1] += d;
}

size_t ErrorMap::tree_find(int64_t target) const {
  // The largest prefix of tiles whose sum is <= target; the tile after it holds target.
  const size_t n = tree_.size();
  size_t pos = 0, step = 1;
  while (step * 2 <= n) step *= 2;
  for (; step > 0; step /= 2)
    if (pos + step <= n && tree_[pos + step - 1] <= target) {
      pos += step;
      target -= tree_[pos - 1];
    }
  return std::min(pos, n - 1);
}

double ErrorMap::uniform_share_now() const { return seeded_ && fixed_total_ > 0 ? opt_.uniform_share : 1.0; }

int64_t ErrorMap::kept_pixel(int64_t t, int64_t at) const {
  const TileRect r = tile_rect(t);
  const int64_t in_tile = kept_[static_cast<size_t>(at)];
  return (r.image * height_ + r.row + in_tile / opt_.tile) * width_ + r.col + in_tile % opt_.tile;
}

torch::Tensor ErrorMap::probabilities() const {
  auto p = torch::empty({tiles()}, torch::kDouble);
  double* out = p.data_ptr<double>();
  const double share = uniform_share_now();
  const double per_pixel = share / static_cast<double>(drawable_pixels());
  const double per_error = share < 1.0 ? (1.0 - share) / static_cast<double>(fixed_total_) : 0.0;
  for (size_t t = 0; t < error_.size(); ++t)
    out[t] = counts_[t] > 0 ? per_pixel * counts_[t] + per_error * static_cast<double>(fixed_[t]) : 0.0;
  return p;
}

torch::Tensor ErrorMap::draw(int64_t n, torch::Generator& gen) {
  const auto u = torch::rand({n, 3}, gen, torch::kDouble);
  const auto ua = u.accessor<double, 2>();
  auto out = torch::empty({n}, torch::kLong);
  int64_t* idx = out.data_ptr<int64_t>();
  const double share = uniform_share_now();
  const int64_t pixels = drawable_pixels();
  // A uniform in [0, 1) to an offset in [0, size).
  const auto offset = [](double u, int64_t size) {
    return std::min<int64_t>(static_cast<int64_t>(u * static_cast<double>(size)), size - 1);
  };
  for (int64_t i = 0; i < n; ++i) {
    const double pick = ua[i][0];
    if (pick < share) {
      // The uniform part: a drawable pixel, each equally likely.
      const int64_t k = offset(pick / share, pixels);
      if (kept_start_.empty()) {
        idx[i] = k;
        continue;
      }
      const auto t =
          static_cast<int64_t>(std::upper_bound(kept_start_.begin(), kept_start_.end(), k) - kept_start_.begin()) - 1;
      idx[i] = kept_pixel(t, k);
      continue;
    }
    // The error part: a tile in proportion to its error, then a drawable pixel inside it.
    const auto t = static_cast<int64_t>(tree_find(offset((pick - share) / (1.0 - share), fixed_total_)));
    if (!kept_start_.empty()) {
      idx[i] = kept_pixel(t, kept_start_[static_cast<size_t>(t)] + offset(ua[i][1], kept_count(t)));
      continue;
    }
    const TileRect r = tile_rect(t);
    idx[i] = (r.image * height_ + r.row + offset(ua[i][1], r.height)) * width_ + r.col + offset(ua[i][2], r.width);
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
    rebuild_tree();
  }
  const int64_t pixel_count = images_ * height_ * width_;
  for (int64_t i = 0; i < n; ++i) {
    if (p[i] < 0 || p[i] >= pixel_count) throw std::invalid_argument("ErrorMap::observe: pixel index out of range");
    if (!std::isfinite(e[i])) continue;  // a skipped (non-finite) step teaches nothing
    const auto t = static_cast<size_t>(tile_of(p[i]));
    error_[t] += kErrorBlend * (e[i] - error_[t]);
    const int64_t f = fixed_error(t);
    add_to_tree(t, f - fixed_[t]);
    fixed_[t] = f;
  }
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
  rebuild_tree();
}

}  // namespace ablenerf
