#pragma once
// LPIPS v0.1 with the AlexNet backbone (Zhang et al. 2018), inference only.
// Weights: a torch.save dictionary with AlexNet's five convs (features.{0,3,6,8,10}.{weight,bias})
// and the five linear calibration layers (lin0..lin4.weight); see assets/LPIPS_WEIGHTS.md.
#include <torch/torch.h>

#include <array>
#include <string>
#include <vector>

namespace ablenerf {

// The default weights file: $ABLENERF_LPIPS_WEIGHTS when set (returned even if the file is missing,
// so a bad setting is reported rather than silently ignored); else the first existing file of
// lpips_weights_candidates(); else "" (the caller should say LPIPS is skipped).
std::string default_lpips_weights_path();

// Where default_lpips_weights_path() looks, in order: <binary's folder>/../share/ablenerf/assets/
// (an installed tree: cmake --install, the .deb), <binary's folder>/../assets/ (a copied tree),
// <source tree>/assets/lpips_alex_v0.1.pt (the shipped fp16 copy, assets/LPIPS_WEIGHTS.md),
// <source tree>/../shared/weights/ (the project's fp32 original; optional, used when present).
std::vector<std::string> lpips_weights_candidates();

class Lpips {
 public:
  // Smallest image side AlexNet accepts: conv1 (11, stride 4, pad 2) must leave >= 7 columns so
  // that two 3/2 max-pools still see a 3-wide window.
  static constexpr int64_t kMinSide = 31;
  static constexpr int kLayers = 5;

  // Throws InputError(path, key, ...) for a missing/unreadable file, a missing key or a tensor
  // of the wrong shape.
  explicit Lpips(const std::string& weights_path);

  // Moves the weights (and later computations) to a device.
  void to(const torch::Device& device);

  // Distance between two (H,W,3) images in [0,1] of the same shape (sides >= kMinSide).
  double distance(const torch::Tensor& img, const torch::Tensor& ref) const;

  // Batched: (N,H,W,3) pairs in [0,1] -> (N) float distances on the weights' device.
  torch::Tensor distances(const torch::Tensor& imgs, const torch::Tensor& refs) const;

  // Batched on network inputs: (N,3,H,W) in [-1,1] -> (N), as the LPIPS package's forward.
  torch::Tensor forward_nchw(const torch::Tensor& x0, const torch::Tensor& x1) const;

 private:
  std::array<torch::Tensor, kLayers> features(const torch::Tensor& x) const;

  std::array<torch::Tensor, kLayers> conv_w_, conv_b_, lin_w_;
  torch::Tensor shift_, scale_;
};

}  // namespace ablenerf
