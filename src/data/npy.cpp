#include "data/npy.h"

#include <cstring>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

// The value of `key` in the header dict ({'descr': '<f8', 'fortran_order': False, 'shape': (3, 17), }),
// as the raw text up to the next top-level comma or closing brace.
std::string dict_value(const std::string& h, const std::string& key, const std::string& origin) {
  size_t k = std::string::npos;
  for (const char q : {'\'', '"'}) {
    k = h.find(std::string(1, q) + key + q);
    if (k != std::string::npos) break;
  }
  if (k == std::string::npos) throw InputError(origin, key, "missing from the header");
  size_t i = h.find(':', k);
  if (i == std::string::npos) throw InputError(origin, key, "malformed header");
  ++i;
  while (i < h.size() && h[i] == ' ') ++i;
  size_t j = i;
  int depth = 0;
  for (; j < h.size(); ++j) {
    if (h[j] == '(') ++depth;
    else if (h[j] == ')') --depth;
    else if ((h[j] == ',' || h[j] == '}') && depth == 0) break;
  }
  if (depth != 0 || j >= h.size()) throw InputError(origin, key, "malformed header");
  return h.substr(i, j - i);
}

}  // namespace

NpyArray parse_npy(const std::string& b, const std::string& origin) {
  if (b.size() < 10 || std::memcmp(b.data(), "\x93NUMPY", 6) != 0) throw InputError(origin, "header", "not a .npy file");
  const auto u8 = [&](size_t i) { return static_cast<unsigned char>(b[i]); };
  const int major = u8(6);
  size_t header_len, start;
  if (major == 1) {
    header_len = u8(8) | (u8(9) << 8);
    start = 10;
  } else if (major == 2 || major == 3) {
    if (b.size() < 12) throw InputError(origin, "header", "truncated");
    header_len = u8(8) | (u8(9) << 8) | (static_cast<size_t>(u8(10)) << 16) | (static_cast<size_t>(u8(11)) << 24);
    start = 12;
  } else {
    throw InputError(origin, "header", "unsupported .npy version " + std::to_string(major));
  }
  if (header_len > b.size() - start) throw InputError(origin, "header", "header length past the end of the file");
  const std::string h = b.substr(start, header_len);
  std::string descr = dict_value(h, "descr", origin);
  if (descr.size() >= 2 && (descr.front() == '\'' || descr.front() == '"')) descr = descr.substr(1, descr.size() - 2);
  const std::string order = dict_value(h, "fortran_order", origin);
  if (order != "False" && order != "True") throw InputError(origin, "fortran_order", "expected True or False");
  const bool fortran = order == "True";
  int size;
  bool big;
  if (descr == "<f8" || descr == ">f8") size = 8, big = descr[0] == '>';
  else if (descr == "<f4" || descr == ">f4") size = 4, big = descr[0] == '>';
  else throw InputError(origin, "descr", "dtype '" + descr + "' not supported (need float32 or float64)");
  const std::string sh = dict_value(h, "shape", origin);
  if (sh.size() < 2 || sh.front() != '(' || sh.back() != ')') throw InputError(origin, "shape", "expected a tuple");
  NpyArray a;
  int64_t count = 1;
  std::string num;
  for (size_t i = 1; i < sh.size(); ++i) {
    const char c = sh[i];
    if (c >= '0' && c <= '9') {
      num += c;
      if (num.size() > 12) throw InputError(origin, "shape", "dimension too large");
    } else if (c == ',' || c == ')') {
      if (!num.empty()) {
        const int64_t d = std::stoll(num);
        if (d != 0 && count > (int64_t(1) << 40) / d) throw InputError(origin, "shape", "too many elements");
        count *= d;
        a.shape.push_back(d);
        num.clear();
      }
    } else if (c != ' ') {
      throw InputError(origin, "shape", "expected whole numbers");
    }
  }
  const size_t data_start = start + header_len;
  const uint64_t need = static_cast<uint64_t>(count) * static_cast<uint64_t>(size);
  if (b.size() - data_start != need)
    throw InputError(origin, "data", "expected " + std::to_string(need) + " bytes, file has " + std::to_string(b.size() - data_start));
  std::vector<double> raw(static_cast<size_t>(count));
  for (int64_t i = 0; i < count; ++i) {
    unsigned char v[8];
    std::memcpy(v, b.data() + data_start + static_cast<size_t>(i) * static_cast<size_t>(size), static_cast<size_t>(size));
    if (big)
      for (int k = 0; k < size / 2; ++k) std::swap(v[k], v[size - 1 - k]);
    if (size == 8) {
      double d;
      std::memcpy(&d, v, 8);
      raw[static_cast<size_t>(i)] = d;
    } else {
      float f;
      std::memcpy(&f, v, 4);
      raw[static_cast<size_t>(i)] = f;
    }
  }
  if (!fortran || a.shape.size() < 2) {
    a.data = std::move(raw);
    return a;
  }
  // Fortran order: the first index varies fastest. Re-index into C order.
  a.data.resize(raw.size());
  const size_t nd = a.shape.size();
  std::vector<int64_t> idx(nd, 0);
  for (size_t f = 0; f < raw.size(); ++f) {
    size_t c = 0;
    for (size_t k = 0; k < nd; ++k) c = c * static_cast<size_t>(a.shape[k]) + static_cast<size_t>(idx[k]);
    a.data[c] = raw[f];
    for (size_t k = 0; k < nd; ++k) {
      if (++idx[k] < a.shape[k]) break;
      idx[k] = 0;
    }
  }
  return a;
}

NpyArray read_npy(const std::string& path) { return parse_npy(read_file(path), path); }

}  // namespace ablenerf
