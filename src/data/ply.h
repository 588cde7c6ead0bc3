#pragma once
// The vertex positions of a PLY point cloud (nerfstudio's sparse_pc.ply, written by ns-process-data
// beside transforms.json), ASCII or binary little-endian, read without LibTorch and fuzzed
// (fuzz/fuzz_ply.cpp). The first element must be "vertex" with scalar properties x, y, z (any of
// PLY's scalar types; other scalar properties such as colours are skipped); what follows the
// vertices is not read. Refusals are InputErrors naming the file and "header", "vertex" or "data";
// non-finite coordinates are refused.
#include <array>
#include <string>
#include <vector>

namespace ablenerf {

// Parses a whole PLY file held in memory; `origin` names it in errors.
std::vector<std::array<double, 3>> parse_ply_points(const std::string& bytes, const std::string& origin);
// Reads and parses the PLY file at `path`.
std::vector<std::array<double, 3>> read_ply_points(const std::string& path);

}  // namespace ablenerf
