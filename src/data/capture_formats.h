#pragma once
// The readers behind capture.cpp's registry, one pair per format (detect, read; capture.h). Private
// to src/data: everything else reads captures through read_capture.
#include <string>
#include <vector>

#include "data/capture.h"

namespace ablenerf {

// transforms_json.cpp
bool is_blender_capture(const std::string& root);
void read_blender_capture(const std::string& root, const std::vector<std::string>& splits, int downscale, Capture& out);
bool is_transforms_capture(const std::string& root);
void read_transforms_capture(const std::string& root, const std::vector<std::string>& splits, int downscale,
                             Capture& out);
// colmap_capture.cpp
bool is_colmap_capture(const std::string& root);
void read_colmap_capture(const std::string& root, const std::vector<std::string>& splits, int downscale, Capture& out);
// llff_capture.cpp
bool is_llff_capture(const std::string& root);
void read_llff_capture(const std::string& root, const std::vector<std::string>& splits, int downscale, Capture& out);

}  // namespace ablenerf
