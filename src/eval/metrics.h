#pragma once
// Image quality metrics on (H,W,3) float images in [0,1] (docs/MODEL.md, section 9): PSNR and two SSIM variants.
// Inputs may live on any device and have any floating dtype; the arithmetic runs in float64 so
// that scores do not depend on the input precision. LPIPS lives in eval/lpips.h.
#include <torch/torch.h>

#include <string>

#include "eval/eval_config.h"

namespace ablenerf {

// PSNR in dB for data range 1: -10 log10(MSE) over every pixel and channel.
// Identical images (MSE == 0) give +infinity (std::numeric_limits<double>::infinity()),
// always; callers that serialise to JSON must handle it (JSON has no infinity).
// With `mask` ((H,W) bool, defined): over the pixels where it is true only (a capture's masks:
// the "unmasked" scores of eval); no true pixel gives NaN.
double psnr(const torch::Tensor& img, const torch::Tensor& ref, const torch::Tensor& mask = torch::Tensor());
// The same from a mean squared error (MSE == 0 gives +infinity).
double psnr_from_mse(double mse);

// Mean squared error over every pixel and channel (float64).
double mse(const torch::Tensor& img, const torch::Tensor& ref, const torch::Tensor& mask = torch::Tensor());

// Parses "standard" / "release"; throws InputError(source, field, ...) for anything else.
SsimVariant parse_ssim_variant(const std::string& name, const std::string& source = "",
                               const std::string& field = "ssim");

// SSIM window parameters shared by both variants (data range 1).
constexpr int kSsimWindow = 11;
constexpr double kSsimSigma = 1.5;
constexpr double kSsimK1 = 0.01;
constexpr double kSsimK2 = 0.03;

// Mean SSIM of two (H,W,C) images of the same shape. With `mask` ((H,W) bool, defined), the mean
// of the SSIM map over the windows centred on true pixels (the standard variant's map is the
// valid part, centres 5 pixels in from each edge); NaN when there is none.
double ssim(const torch::Tensor& img, const torch::Tensor& ref, SsimVariant variant = SsimVariant::Standard,
            const torch::Tensor& mask = torch::Tensor());

// Reads a PNG as float (H,W,3) in [0,1] for scoring. RGBA is composited on a white background
// (rgb * a + (1 - a)), the Blender dataset convention used for training and evaluation;
// greyscale is replicated to three channels. Throws InputError naming the file.
torch::Tensor read_rgb_for_metrics(const std::string& path);

}  // namespace ablenerf
