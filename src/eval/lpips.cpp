#include "eval/lpips.h"

#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <vector>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

namespace F = torch::nn::functional;

// AlexNet layout of torchvision's `features` Sequential: the indices of the five convs, their
// output channels, input channels, kernel sizes, strides and paddings (assets/LPIPS_WEIGHTS.md).
struct ConvSpec {
  int index;
  int64_t out, in, kernel, stride, padding;
};
constexpr std::array<ConvSpec, Lpips::kLayers> kConvs{{
    {0, 64, 3, 11, 4, 2},
    {3, 192, 64, 5, 1, 2},
    {6, 384, 192, 3, 1, 1},
    {8, 256, 384, 3, 1, 1},
    {10, 256, 256, 3, 1, 1},
}};
// Max-pool (kernel 3, stride 2) before conv2 and conv3 only.
constexpr int64_t kPoolKernel = 3, kPoolStride = 2;
constexpr bool kPoolBefore[Lpips::kLayers] = {false, true, true, false, false};

// LPIPS's ScalingLayer constants, per RGB channel, for inputs in [-1, 1].
constexpr float kShift[3] = {-0.030f, -0.088f, -0.188f};
constexpr float kScale[3] = {0.458f, 0.448f, 0.450f};
// Added to the channel norm before dividing (LPIPS normalize_tensor).
constexpr double kNormEps = 1e-10;
// File name of the weights in assets/ and in the shared folder.
constexpr const char* kLpipsFile = "lpips_alex_v0.1.pt";

std::string shape_str(at::IntArrayRef s) {
  std::ostringstream o;
  o << s;
  return o.str();
}

torch::Tensor take(const c10::Dict<c10::IValue, c10::IValue>& dict, const std::string& path, const std::string& key,
                   std::vector<int64_t> shape) {
  auto it = dict.find(c10::IValue(key));
  if (it == dict.end()) throw InputError(path, key, "missing from the LPIPS weights");
  if (!it->value().isTensor()) throw InputError(path, key, "is not a tensor");
  torch::Tensor t = it->value().toTensor();
  if (t.sizes() != at::IntArrayRef(shape))
    throw InputError(path, key, "has shape " + shape_str(t.sizes()) + ", expected " + shape_str(shape));
  if (!t.is_floating_point()) throw InputError(path, key, "is not a floating-point tensor");
  return t.to(torch::kFloat).contiguous();
}

}  // namespace

std::vector<std::string> lpips_weights_candidates() {
  namespace fs = std::filesystem;
  std::vector<std::string> out;
  // An installed tree first (cmake --install, the .deb): BIN_DIR/../share/ablenerf/assets, the
  // binary's real location with links resolved; then a copied tree's BIN_DIR/../assets.
  std::error_code ec;
  const fs::path exe = fs::read_symlink("/proc/self/exe", ec);
  if (!ec && !exe.empty()) {
    out.push_back(
        (exe.parent_path() / ".." / "share" / "ablenerf" / "assets" / kLpipsFile).lexically_normal().string());
    out.push_back((exe.parent_path() / ".." / "assets" / kLpipsFile).lexically_normal().string());
  }
  // The copy shipped in the source tree this binary was built from.
  out.push_back((fs::path(ABLENERF_SOURCE_DIR) / "assets" / kLpipsFile).string());
  // The project's shared folder beside the repository (the fp32 original).
  out.push_back((fs::path(ABLENERF_SOURCE_DIR) / ".." / "shared" / "weights" / kLpipsFile).lexically_normal().string());
  return out;
}

std::string default_lpips_weights_path() {
  if (const char* env = std::getenv("ABLENERF_LPIPS_WEIGHTS"); env && *env) return env;
  std::error_code ec;
  for (const std::string& p : lpips_weights_candidates())
    if (std::filesystem::is_regular_file(p, ec)) return p;
  return std::string();
}

Lpips::Lpips(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw InputError(path, "", "LPIPS weights file not found");
  const std::string file = read_file(path);
  const std::vector<char> bytes(file.begin(), file.end());

  c10::IValue root;
  try {
    root = torch::pickle_load(bytes);
  } catch (const c10::Error& e) {
    throw InputError(path, "", std::string("not a torch.save file: ") + e.what_without_backtrace());
  }
  if (!root.isGenericDict()) throw InputError(path, "", "expected a torch.save dictionary of tensors");
  const auto dict = root.toGenericDict();

  for (int k = 0; k < kLayers; ++k) {
    const ConvSpec& s = kConvs[k];
    const std::string base = "features." + std::to_string(s.index);
    conv_w_[k] = take(dict, path, base + ".weight", {s.out, s.in, s.kernel, s.kernel});
    conv_b_[k] = take(dict, path, base + ".bias", {s.out});
    lin_w_[k] = take(dict, path, "lin" + std::to_string(k) + ".weight", {1, s.out, 1, 1});
  }
  shift_ = torch::tensor({kShift[0], kShift[1], kShift[2]}).view({1, 3, 1, 1});
  scale_ = torch::tensor({kScale[0], kScale[1], kScale[2]}).view({1, 3, 1, 1});
}

void Lpips::to(const torch::Device& device) {
  for (int k = 0; k < kLayers; ++k) {
    conv_w_[k] = conv_w_[k].to(device);
    conv_b_[k] = conv_b_[k].to(device);
    lin_w_[k] = lin_w_[k].to(device);
  }
  shift_ = shift_.to(device);
  scale_ = scale_.to(device);
}

std::array<torch::Tensor, Lpips::kLayers> Lpips::features(const torch::Tensor& x) const {
  std::array<torch::Tensor, kLayers> out;
  torch::Tensor h = (x - shift_) / scale_;
  for (int k = 0; k < kLayers; ++k) {
    if (kPoolBefore[k]) h = F::max_pool2d(h, F::MaxPool2dFuncOptions(kPoolKernel).stride(kPoolStride));
    h = F::conv2d(h, conv_w_[k],
                  F::Conv2dFuncOptions().bias(conv_b_[k]).stride(kConvs[k].stride).padding(kConvs[k].padding));
    h = torch::relu(h);
    out[k] = h;
  }
  return out;
}

torch::Tensor Lpips::forward_nchw(const torch::Tensor& x0, const torch::Tensor& x1) const {
  TORCH_CHECK(x0.dim() == 4 && x0.size(1) == 3, "lpips: expected (N,3,H,W), got ", x0.sizes());
  TORCH_CHECK(x0.sizes() == x1.sizes(), "lpips: shapes differ: ", x0.sizes(), " vs ", x1.sizes());
  TORCH_CHECK(x0.size(2) >= kMinSide && x0.size(3) >= kMinSide, "lpips: images must be at least ", kMinSide, "x",
              kMinSide, ", got ", x0.sizes());
  torch::NoGradGuard no_grad;
  const auto dev = conv_w_[0].device();
  const auto f0 = features(x0.to(dev, torch::kFloat));
  const auto f1 = features(x1.to(dev, torch::kFloat));
  torch::Tensor total = torch::zeros({x0.size(0)}, conv_w_[0].options());
  for (int k = 0; k < kLayers; ++k) {
    auto n0 = f0[k] / (f0[k].pow(2).sum(1, /*keepdim=*/true).sqrt() + kNormEps);
    auto n1 = f1[k] / (f1[k].pow(2).sum(1, /*keepdim=*/true).sqrt() + kNormEps);
    auto weighted = F::conv2d((n0 - n1).pow(2), lin_w_[k]);  // (N,1,h,w)
    total = total + weighted.mean({1, 2, 3});
  }
  return total;
}

torch::Tensor Lpips::distances(const torch::Tensor& imgs, const torch::Tensor& refs) const {
  TORCH_CHECK(imgs.dim() == 4 && imgs.size(3) == 3, "lpips: expected (N,H,W,3), got ", imgs.sizes());
  // [0,1] -> [-1,1], channels first.
  auto prep = [](const torch::Tensor& t) { return (t.to(torch::kFloat) * 2.0f - 1.0f).permute({0, 3, 1, 2}); };
  return forward_nchw(prep(imgs), prep(refs));
}

double Lpips::distance(const torch::Tensor& img, const torch::Tensor& ref) const {
  TORCH_CHECK(img.dim() == 3, "lpips: expected an (H,W,3) image, got ", img.sizes());
  return distances(img.unsqueeze(0), ref.unsqueeze(0)).item<double>();
}

}  // namespace ablenerf
