// COLMAP's text model files (cameras.txt, images.txt, points3D.txt): whitespace-separated fields,
// '#' comment lines, numbers parsed locale-independently and range-checked (colmap_model.h).
#include <algorithm>
#include <charconv>
#include <cmath>
#include <limits>
#include <string>
#include <string_view>
#include <system_error>
#include <unordered_set>
#include <vector>

#include "data/colmap_model.h"
#include "data/colmap_model_internal.h"
#include "util/errors.h"

namespace ablenerf {

using namespace colmap_detail;

namespace {

struct TextLine {
  size_t number;  // 1-based
  std::string_view text;
};

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }

bool is_blank(std::string_view s) { return std::all_of(s.begin(), s.end(), is_space); }

// The lines of a COLMAP text file without the comments (first non-blank character '#'). Blank
// lines are kept: in images.txt an image without observations has an empty second line.
std::vector<TextLine> text_lines(const std::string& text) {
  std::vector<TextLine> out;
  size_t start = 0, number = 1;
  while (start < text.size()) {
    size_t end = text.find('\n', start);
    if (end == std::string::npos) end = text.size();
    std::string_view line(text.data() + start, end - start);
    if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
    const auto first = std::find_if_not(line.begin(), line.end(), is_space);
    if (first == line.end() || *first != '#') out.push_back({number, line});
    start = end + 1;
    ++number;
  }
  return out;
}

std::vector<std::string_view> split_fields(std::string_view line) {
  std::vector<std::string_view> out;
  size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && is_space(line[i])) ++i;
    const size_t begin = i;
    while (i < line.size() && !is_space(line[i])) ++i;
    if (i > begin) out.push_back(line.substr(begin, i - begin));
  }
  return out;
}

std::string line_label(const TextLine& l) { return "line " + std::to_string(l.number); }

// A decimal number (locale-independent). Non-finite values ("nan", "inf", 1e999) are refused
// unless `any` is set.
double parse_real(std::string_view tok, const std::string& origin, const std::string& field, bool any = false) {
  std::string_view t = tok;
  if (t.size() > 1 && t[0] == '+' && t[1] != '-') t.remove_prefix(1);
  double v = 0;
  const auto [end, ec] = std::from_chars(t.data(), t.data() + t.size(), v);
  if (end != t.data() + t.size() || (ec != std::errc() && ec != std::errc::result_out_of_range))
    throw InputError(origin, field, "expected a number, got '" + printable(tok, kColmapQuoteChars) + "'");
  if (ec == std::errc::result_out_of_range) {
    // from_chars leaves v alone when the literal is out of range; an underflow is a zero.
    if (any) return std::numeric_limits<double>::quiet_NaN();
    throw InputError(origin, field, "'" + printable(tok, kColmapQuoteChars) + "' is out of range of a double");
  }
  if (!any && !std::isfinite(v))
    throw InputError(origin, field, "non-finite value '" + printable(tok, kColmapQuoteChars) + "'");
  return v;
}

// A whole number in [0, max].
uint64_t parse_whole(std::string_view tok, uint64_t max, const std::string& origin, const std::string& field) {
  uint64_t v = 0;
  const auto [end, ec] = std::from_chars(tok.data(), tok.data() + tok.size(), v);
  if (end != tok.data() + tok.size() || (ec != std::errc() && ec != std::errc::result_out_of_range))
    throw InputError(origin, field, "expected a whole number, got '" + printable(tok, kColmapQuoteChars) + "'");
  if (ec == std::errc::result_out_of_range || v > max)
    throw InputError(origin, field,
                     "'" + printable(tok, kColmapQuoteChars) + "' is out of range [0, " + std::to_string(max) + "]");
  return v;
}

}  // namespace

std::vector<ColmapCamera> parse_cameras_txt(const std::string& text, const std::string& origin) {
  std::vector<ColmapCamera> out;
  std::unordered_set<uint32_t> ids;
  for (const TextLine& line : text_lines(text)) {
    if (is_blank(line.text)) continue;
    const auto f = split_fields(line.text);
    const std::string at = line_label(line);
    if (f.size() < 4)
      throw InputError(origin, at,
                       "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got " + std::to_string(f.size()) + " fields");
    ColmapCamera c;
    c.id = static_cast<uint32_t>(parse_whole(f[0], kMaxU32, origin, at + ": CAMERA_ID"));
    const std::string where = at + ": camera " + std::to_string(c.id);
    c.model = std::string(f[1]);
    for (int k = 0; k < kNumCameraModels; ++k)
      if (c.model == kCameraModels[k].name) c.model_id = k;
    if (c.model_id < 0)
      throw InputError(origin, where + ": model",
                       "unknown COLMAP camera model '" + printable(c.model, kColmapQuoteChars) + "'");
    c.width = parse_whole(f[2], kMaxU64, origin, where + ": width");
    c.height = parse_whole(f[3], kMaxU64, origin, where + ": height");
    const size_t np = static_cast<size_t>(kCameraModels[c.model_id].params);
    if (f.size() - 4 != np)
      throw InputError(
          origin, where + ": params",
          c.model + " has " + std::to_string(np) + " parameters, the line gives " + std::to_string(f.size() - 4));
    for (size_t k = 0; k < np; ++k)
      c.params.push_back(parse_real(f[4 + k], origin, where + ": params[" + std::to_string(k) + "]"));
    check_camera(c, origin, where);
    if (!ids.insert(c.id).second) throw InputError(origin, where + ": CAMERA_ID", "duplicate camera id");
    out.push_back(std::move(c));
  }
  return out;
}

std::vector<ColmapImage> parse_images_txt(const std::string& text, const std::string& origin) {
  std::vector<ColmapImage> out;
  std::unordered_set<uint32_t> ids;
  const std::vector<TextLine> lines = text_lines(text);
  // Two lines per image: the pose line, then its 2D points (possibly empty; missing at the very
  // end of the file counts as empty). Blank lines where a pose line is due are skipped.
  for (size_t i = 0; i < lines.size();) {
    if (is_blank(lines[i].text)) {
      ++i;
      continue;
    }
    const TextLine& pose = lines[i];
    const TextLine* points = i + 1 < lines.size() ? &lines[i + 1] : nullptr;
    i += 2;
    const auto f = split_fields(pose.text);
    const std::string at = line_label(pose);
    if (f.size() < 10)
      throw InputError(
          origin, at,
          "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got " + std::to_string(f.size()) + " fields");
    ColmapImage im;
    im.id = static_cast<uint32_t>(parse_whole(f[0], kMaxU32, origin, at + ": IMAGE_ID"));
    const std::string id_at = at + ": image " + std::to_string(im.id);
    for (size_t k = 0; k < 4; ++k) im.qvec[k] = parse_real(f[1 + k], origin, id_at + ": qvec");
    for (size_t k = 0; k < 3; ++k) im.tvec[k] = parse_real(f[5 + k], origin, id_at + ": tvec");
    im.camera_id = static_cast<uint32_t>(parse_whole(f[8], kMaxU32, origin, id_at + ": CAMERA_ID"));
    // The name is the rest of the line, so that a name with spaces survives.
    std::string_view name = pose.text.substr(static_cast<size_t>(f[9].data() - pose.text.data()));
    while (!name.empty() && is_space(name.back())) name.remove_suffix(1);
    im.name = std::string(name);
    const std::string where = at + ": " + image_label(im.id, im.name);
    check_image(im, origin, where);
    if (!ids.insert(im.id).second) throw InputError(origin, where + ": IMAGE_ID", "duplicate image id");
    if (points) {
      const auto p = split_fields(points->text);
      const std::string pat = line_label(*points) + ": " + image_label(im.id, im.name) + ": points2D";
      if (p.size() % 3 != 0)
        throw InputError(origin, pat, "expected X Y POINT3D_ID triples, got " + std::to_string(p.size()) + " fields");
      for (size_t k = 0; k < p.size(); k += 3) {
        parse_real(p[k], origin, pat + " X");
        parse_real(p[k + 1], origin, pat + " Y");
        if (p[k + 2] == "-1") continue;  // an observation without a 3D point
        im.point3d_ids.push_back(parse_whole(p[k + 2], kMaxU64, origin, pat + " POINT3D_ID"));
        if (im.point3d_ids.back() == kNoPoint) im.point3d_ids.pop_back();
      }
    }
    out.push_back(std::move(im));
  }
  return out;
}

std::vector<ColmapPoint> parse_points3d_txt(const std::string& text, const std::string& origin) {
  std::vector<ColmapPoint> out;
  std::unordered_set<uint64_t> ids;
  for (const TextLine& line : text_lines(text)) {
    if (is_blank(line.text)) continue;
    const auto f = split_fields(line.text);
    const std::string at = line_label(line);
    if (f.size() < 8 || (f.size() - 8) % 2 != 0)
      throw InputError(origin, at,
                       "expected POINT3D_ID X Y Z R G B ERROR and (IMAGE_ID POINT2D_IDX) pairs, got " +
                           std::to_string(f.size()) + " fields");
    ColmapPoint p;
    p.id = parse_whole(f[0], kMaxU64, origin, at + ": POINT3D_ID");
    const std::string where = at + ": point " + std::to_string(p.id);
    for (size_t k = 0; k < 3; ++k) p.xyz[k] = parse_real(f[1 + k], origin, where + ": xyz");
    for (size_t k = 0; k < 3; ++k) p.rgb[k] = static_cast<uint8_t>(parse_whole(f[4 + k], 255, origin, where + ": rgb"));
    p.error = parse_real(f[7], origin, where + ": error", /*any=*/true);
    for (size_t k = 8; k < f.size(); ++k) parse_whole(f[k], kMaxU32, origin, where + ": track");
    if (!ids.insert(p.id).second) throw InputError(origin, where + ": POINT3D_ID", "duplicate point id");
    out.push_back(p);
  }
  return out;
}

}  // namespace ablenerf
