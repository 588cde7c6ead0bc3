#include "data/ply.h"

#include <cmath>
#include <cstdint>
#include <cstring>
#include <sstream>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

struct PlyProperty {
  int bytes = 0;    // size in the binary encoding
  char kind = 'f';  // 'i' signed, 'u' unsigned, 'f' floating
  std::string name;
};

// PLY's scalar types (both spellings); false for anything else.
bool scalar_type(const std::string& t, PlyProperty& p) {
  static const struct {
    const char* a;
    const char* b;
    int bytes;
    char kind;
  } types[] = {{"char", "int8", 1, 'i'},     {"uchar", "uint8", 1, 'u'},   {"short", "int16", 2, 'i'},
               {"ushort", "uint16", 2, 'u'}, {"int", "int32", 4, 'i'},     {"uint", "uint32", 4, 'u'},
               {"float", "float32", 4, 'f'}, {"double", "float64", 8, 'f'}};
  for (const auto& ty : types)
    if (t == ty.a || t == ty.b) {
      p.bytes = ty.bytes, p.kind = ty.kind;
      return true;
    }
  return false;
}

// A little-endian scalar of property `p` at `q`, as a double.
double read_binary(const unsigned char* q, const PlyProperty& p) {
  uint64_t u = 0;
  for (int i = 0; i < p.bytes; ++i) u |= static_cast<uint64_t>(q[i]) << (8 * i);
  if (p.kind == 'f') {
    if (p.bytes == 4) {
      const auto v = static_cast<uint32_t>(u);
      float f;
      std::memcpy(&f, &v, 4);
      return f;
    }
    double d;
    std::memcpy(&d, &u, 8);
    return d;
  }
  if (p.kind == 'u') return static_cast<double>(u);
  const int shift = 64 - 8 * p.bytes;  // sign-extend
  return static_cast<double>(static_cast<int64_t>(u << shift) >> shift);
}

// Largest vertex count accepted before any allocation: far beyond any sparse cloud.
constexpr uint64_t kMaxPlyVertices = 50'000'000;

}  // namespace

std::vector<std::array<double, 3>> parse_ply_points(const std::string& bytes, const std::string& origin) {
  const size_t end = bytes.find("end_header");
  if (bytes.compare(0, 4, "ply\n") != 0 && bytes.compare(0, 5, "ply\r\n") != 0)
    throw InputError(origin, "header", "not a PLY file (no 'ply' first line)");
  if (end == std::string::npos) throw InputError(origin, "header", "no end_header line");
  size_t body = bytes.find('\n', end);
  if (body == std::string::npos) throw InputError(origin, "header", "nothing after end_header");
  ++body;
  std::istringstream header(bytes.substr(0, end));
  std::string line, format;
  uint64_t count = 0;
  bool in_vertex = false, seen_element = false;
  std::vector<PlyProperty> props;
  std::getline(header, line);  // "ply"
  while (std::getline(header, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream w(line);
    std::string key;
    w >> key;
    if (key.empty() || key == "comment" || key == "obj_info") continue;
    if (key == "format") {
      std::string version;
      w >> format >> version;
      if (format != "ascii" && format != "binary_little_endian")
        throw InputError(origin, "header", "format '" + format + "' is not supported (ascii or binary_little_endian)");
    } else if (key == "element") {
      std::string name;
      long long n = -1;
      w >> name >> n;
      if (!seen_element) {
        if (name != "vertex")
          throw InputError(origin, "vertex", "the first element must be 'vertex', not '" + name + "'");
        if (w.fail() || n < 0 || static_cast<uint64_t>(n) > kMaxPlyVertices)
          throw InputError(origin, "vertex", "bad vertex count");
        count = static_cast<uint64_t>(n);
        in_vertex = true;
      } else {
        in_vertex = false;
      }
      seen_element = true;
    } else if (key == "property") {
      if (!in_vertex) continue;
      std::string type, name;
      w >> type >> name;
      PlyProperty p;
      if (type == "list") throw InputError(origin, "vertex", "list properties in the vertex element are not supported");
      if (!scalar_type(type, p) || name.empty()) throw InputError(origin, "vertex", "bad property line '" + line + "'");
      p.name = name;
      props.push_back(p);
    } else {
      throw InputError(origin, "header", "unknown header line '" + printable(line, 60) + "'");
    }
  }
  if (format.empty()) throw InputError(origin, "header", "no format line");
  if (!seen_element) throw InputError(origin, "vertex", "no vertex element");
  int ix = -1, iy = -1, iz = -1;
  for (size_t i = 0; i < props.size(); ++i) {
    if (props[i].name == "x") ix = static_cast<int>(i);
    if (props[i].name == "y") iy = static_cast<int>(i);
    if (props[i].name == "z") iz = static_cast<int>(i);
  }
  if (ix < 0 || iy < 0 || iz < 0) throw InputError(origin, "vertex", "needs properties x, y and z");
  std::vector<std::array<double, 3>> out;
  const auto check = [&](const std::array<double, 3>& v, uint64_t i) {
    for (double c : v)
      if (!std::isfinite(c)) throw InputError(origin, "data", "vertex " + std::to_string(i) + " is not finite");
  };
  if (format == "binary_little_endian") {
    size_t row = 0;
    for (const auto& p : props) row += static_cast<size_t>(p.bytes);
    if (count > (bytes.size() - body) / row)
      throw InputError(origin, "data", "truncated: " + std::to_string(count) + " vertices do not fit in the file");
    out.reserve(count);
    std::vector<size_t> offset(props.size());
    for (size_t i = 1; i < props.size(); ++i) offset[i] = offset[i - 1] + static_cast<size_t>(props[i - 1].bytes);
    const auto* base = reinterpret_cast<const unsigned char*>(bytes.data()) + body;
    for (uint64_t i = 0; i < count; ++i) {
      const unsigned char* r = base + i * row;
      const std::array<double, 3> v{read_binary(r + offset[ix], props[ix]), read_binary(r + offset[iy], props[iy]),
                                    read_binary(r + offset[iz], props[iz])};
      check(v, i);
      out.push_back(v);
    }
    return out;
  }
  // ASCII: one vertex per line, one number per property.
  std::istringstream data(bytes.substr(body));
  for (uint64_t i = 0; i < count; ++i) {
    if (!std::getline(data, line))
      throw InputError(origin, "data", "truncated: vertex " + std::to_string(i) + " missing");
    std::istringstream w(line);
    std::vector<double> vals(props.size());
    for (auto& v : vals)
      if (!(w >> v))
        throw InputError(origin, "data",
                         "vertex " + std::to_string(i) + ": expected " + std::to_string(props.size()) + " numbers");
    const std::array<double, 3> v{vals[static_cast<size_t>(ix)], vals[static_cast<size_t>(iy)],
                                  vals[static_cast<size_t>(iz)]};
    check(v, i);
    out.push_back(v);
  }
  return out;
}

std::vector<std::array<double, 3>> read_ply_points(const std::string& path) {
  return parse_ply_points(read_file(path), path);
}

}  // namespace ablenerf
