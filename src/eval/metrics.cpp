#include "eval/metrics.h"

#include <cmath>
#include <limits>

#include "util/errors.h"
#include "util/image_io.h"
#include "eval/eval_config.h"

namespace ablenerf {

namespace {

void check_pair(const torch::Tensor& img, const torch::Tensor& ref, const char* what) {
  TORCH_CHECK(img.dim() == 3, what, ": expected an (H,W,C) image, got ", img.sizes());
  TORCH_CHECK(img.sizes() == ref.sizes(), what, ": image shapes differ: ", img.sizes(), " vs ", ref.sizes());
}

// (H,W,C) -> (1,C,H,W) float64 on the image's device.
torch::Tensor to_nchw_double(const torch::Tensor& im) {
  return im.to(torch::kDouble).permute({2, 0, 1}).unsqueeze(0).contiguous();
}

// Normalised 1-D Gaussian taps centred on the middle tap.
torch::Tensor gaussian_taps(const torch::TensorOptions& opts) {
  const double centre = (kSsimWindow - 1) / 2.0;
  auto x = torch::arange(kSsimWindow, opts) - centre;
  auto g = torch::exp(-0.5 * (x / kSsimSigma).pow(2));
  return g / g.sum();
}

// Separable per-channel Gaussian blur; `pad` zeros on each side (0 = valid convolution).
// Zero padding commutes with separability: a padded column is zero after the vertical pass.
torch::Tensor blur(const torch::Tensor& x, const torch::Tensor& taps, int64_t pad) {
  const int64_t c = x.size(1);
  auto wv = taps.view({1, 1, kSsimWindow, 1}).expand({c, 1, kSsimWindow, 1}).contiguous();
  auto wh = taps.view({1, 1, 1, kSsimWindow}).expand({c, 1, 1, kSsimWindow}).contiguous();
  namespace F = torch::nn::functional;
  auto y = F::conv2d(x, wv, F::Conv2dFuncOptions().padding({pad, 0}).groups(c));
  return F::conv2d(y, wh, F::Conv2dFuncOptions().padding({0, pad}).groups(c));
}

}  // namespace

double mse(const torch::Tensor& img, const torch::Tensor& ref, const torch::Tensor& mask) {
  check_pair(img, ref, "mse");
  const auto sq = (img.to(torch::kDouble) - ref.to(torch::kDouble).to(img.device())).pow(2);
  if (!mask.defined()) return sq.mean().item<double>();
  TORCH_CHECK(mask.dim() == 2 && mask.size(0) == img.size(0) && mask.size(1) == img.size(1),
              "mse: the mask must be (H,W) of the images, got ", mask.sizes());
  return sq.mean(-1).masked_select(mask.to(sq.device(), torch::kBool)).mean().item<double>();
}

double psnr_from_mse(double mse) {
  if (mse == 0.0) return std::numeric_limits<double>::infinity();
  return -10.0 * std::log10(mse);
}

double psnr(const torch::Tensor& img, const torch::Tensor& ref, const torch::Tensor& mask) {
  return psnr_from_mse(mse(img, ref, mask));
}

SsimVariant parse_ssim_variant(const std::string& name, const std::string& source, const std::string& field) {
  if (const auto v = enum_from_name<SsimVariant>(name)) return *v;
  throw InputError(source, field, "unknown SSIM variant '" + name + "' (use standard or release)");
}

double ssim(const torch::Tensor& img, const torch::Tensor& ref, SsimVariant variant, const torch::Tensor& mask) {
  check_pair(img, ref, "ssim");
  TORCH_CHECK(!mask.defined() || (mask.dim() == 2 && mask.size(0) == img.size(0) && mask.size(1) == img.size(1)),
              "ssim: the mask must be (H,W) of the images, got ", mask.sizes());
  const bool standard = variant == SsimVariant::Standard;
  TORCH_CHECK(!standard || (img.size(0) >= kSsimWindow && img.size(1) >= kSsimWindow),
              "ssim (standard): images must be at least ", kSsimWindow, "x", kSsimWindow, ", got ", img.sizes());
  const int64_t pad = standard ? 0 : kSsimWindow / 2;
  const double c1 = kSsimK1 * kSsimK1, c2 = kSsimK2 * kSsimK2;

  auto x = to_nchw_double(img), y = to_nchw_double(ref.to(img.device()));
  auto taps = gaussian_taps(x.options());
  auto mu_x = blur(x, taps, pad), mu_y = blur(y, taps, pad);
  auto var_x = blur(x * x, taps, pad) - mu_x * mu_x;
  auto var_y = blur(y * y, taps, pad) - mu_y * mu_y;
  auto cov = blur(x * y, taps, pad) - mu_x * mu_y;
  if (standard) {
    // multinerf guards against tiny negative variances from cancellation.
    var_x = var_x.clamp_min(0.0);
    var_y = var_y.clamp_min(0.0);
    cov = torch::sign(cov) * torch::minimum(torch::sqrt(var_x * var_y), cov.abs());
  }
  auto num = (2.0 * mu_x * mu_y + c1) * (2.0 * cov + c2);
  auto den = (mu_x * mu_x + mu_y * mu_y + c1) * (var_x + var_y + c2);
  if (!mask.defined()) return (num / den).mean().item<double>();
  auto per_pixel = (num / den).mean(1).squeeze(0);  // (H', W'), the channels' mean
  auto centres = mask.to(per_pixel.device(), torch::kBool);
  if (standard)
    centres = centres.slice(0, kSsimWindow / 2, kSsimWindow / 2 + per_pixel.size(0))
                  .slice(1, kSsimWindow / 2, kSsimWindow / 2 + per_pixel.size(1));
  return per_pixel.masked_select(centres).mean().item<double>();
}

torch::Tensor read_rgb_for_metrics(const std::string& path) {
  torch::Tensor im = read_png(path).to(torch::kFloat).div_(255.0f);
  if (im.size(2) == 1) return im.expand({-1, -1, 3}).contiguous();
  if (im.size(2) == 4) {
    auto rgb = im.slice(2, 0, 3), a = im.slice(2, 3, 4);
    return rgb * a + (1.0f - a);  // white background, as the dataset loader does
  }
  return im;
}

}  // namespace ablenerf
