#pragma once
// PNG reading and writing as tensors, strict: truncated or corrupt files raise InputError.
// The libpng work lives in util/png_codec.h (torch-free, fuzzed); these are thin tensor wrappers.
#include <torch/torch.h>

#include <string>

#include "util/png_codec.h"  // png_size

namespace ablenerf {

// Decodes an 8-bit (or 16-bit, reduced to 8) PNG into a uint8 tensor (H, W, C) with C in {1,3,4}
// (grey+alpha is expanded to RGBA, palettes to RGB(A)). Throws InputError naming the file.
torch::Tensor read_png(const std::string& path);

// A decoded image (PNG or JPEG: util/image_codec.h) as a uint8 (H, W, C) tensor (a copy).
torch::Tensor image_tensor(const Image8& image);

// Writes a uint8 (H,W,C) or float (H,W,C) in [0,1] tensor, C in {1,3,4}. Floats are clamped
// and rounded half-up (x*255 + 0.5), like torchvision's save_image. The file is written to a
// temporary name and renamed, so an existing file is never left half-written.
void write_png(const std::string& path, const torch::Tensor& image);

// Float (H,W,C) in [0,1] -> uint8 with the same rounding as write_png.
torch::Tensor to_uint8(const torch::Tensor& image);

// Box-downscale an (H,W,C) float image by an integer factor (H and W must be divisible).
torch::Tensor box_downscale(const torch::Tensor& image, int factor);

}  // namespace ablenerf
