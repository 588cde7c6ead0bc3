#include "data/npy.h"

#include <cstring>
#include <limits>
#include <string_view>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

// Longest excerpt of an input's text quoted in an error message.
constexpr size_t kNpyQuoteChars = 40;

// The format: 6 magic bytes, major and minor version, the header length (uint16 LE in 1.0,
// uint32 LE in 2.0 and 3.0), the header (a Python dict literal padded with spaces and a '\n'),
// then the raw elements.
constexpr char kMagic[] = "\x93NUMPY";
constexpr size_t kMagicBytes = 6;

struct Header {
  bool has_descr = false, has_order = false, has_shape = false;
  std::string descr;
  bool fortran = false;
  std::vector<int64_t> shape;
};

// A reader of the header dict numpy writes, e.g.
//   {'descr': '<f8', 'fortran_order': False, 'shape': (20, 17), }
// Values can be a quoted string, True / False, or a tuple of whole numbers (a trailing comma, as
// in "(5,)", and Python 2's "5L" accepted). Keys other than the three numpy writes are skipped
// when their value is one of those kinds.
class HeaderParser {
 public:
  HeaderParser(std::string_view text, const std::string& origin) : s_(text), origin_(origin) {}

  Header parse() {
    Header h;
    space();
    expect('{', "the header is not a dict");
    while (true) {
      space();
      if (peek() == '}') {
        ++i_;
        break;
      }
      const std::string key = string_literal("a quoted key");
      space();
      expect(':', "expected ':' after '" + printable(key, kNpyQuoteChars) + "'");
      space();
      if (key == "descr") {
        if (h.has_descr) fail("header", "'descr' given twice");
        if (peek() != '\'' && peek() != '"')
          fail("descr", "expected a dtype string such as '<f8' (structured dtypes are not supported)");
        h.descr = string_literal("a dtype string");
        h.has_descr = true;
      } else if (key == "fortran_order") {
        if (h.has_order) fail("header", "'fortran_order' given twice");
        h.fortran = boolean("fortran_order");
        h.has_order = true;
      } else if (key == "shape") {
        if (h.has_shape) fail("header", "'shape' given twice");
        h.shape = tuple();
        h.has_shape = true;
      } else {
        skip_value(key);
      }
      space();
      if (peek() == ',') {
        ++i_;
      } else if (peek() != '}') {
        fail("header", "expected ',' or '}' after the value of '" + printable(key, kNpyQuoteChars) + "'");
      }
    }
    space();
    if (i_ != s_.size()) fail("header", "unexpected text after the dict");
    if (!h.has_descr) fail("header", "no 'descr' key");
    if (!h.has_order) fail("header", "no 'fortran_order' key");
    if (!h.has_shape) fail("header", "no 'shape' key");
    return h;
  }

 private:
  [[noreturn]] void fail(const std::string& field, const std::string& what) const {
    throw InputError(origin_, field, what);
  }
  char peek() const { return i_ < s_.size() ? s_[i_] : '\0'; }
  void space() {
    while (i_ < s_.size() && (s_[i_] == ' ' || s_[i_] == '\t' || s_[i_] == '\n' || s_[i_] == '\r')) ++i_;
  }
  void expect(char c, const std::string& what) {
    if (peek() != c) fail("header", what);
    ++i_;
  }
  // 'text' or "text", without escapes (numpy's keys and dtype strings have none).
  std::string string_literal(const char* what) {
    const char q = peek();
    if (q != '\'' && q != '"') fail("header", std::string("expected ") + what);
    const size_t end = s_.find(q, i_ + 1);
    if (end == std::string_view::npos) fail("header", "unterminated string");
    std::string out(s_.substr(i_ + 1, end - i_ - 1));
    i_ = end + 1;
    return out;
  }
  bool boolean(const std::string& field) {
    for (const char* word : {"True", "False"}) {
      const size_t n = std::strlen(word);
      if (s_.substr(i_, n) == word) {
        i_ += n;
        return word[0] == 'T';
      }
    }
    fail(field, "expected True or False");
  }
  // (d0, d1, ...) of whole numbers; "()" is a 0-d array.
  std::vector<int64_t> tuple() {
    constexpr int64_t kMaxDim = int64_t{1} << 62;
    if (peek() != '(') fail("shape", "expected a tuple such as (20, 17)");
    ++i_;
    std::vector<int64_t> dims;
    while (true) {
      space();
      if (peek() == ')') {
        ++i_;
        return dims;
      }
      if (peek() < '0' || peek() > '9') fail("shape", "expected whole numbers");
      int64_t d = 0;
      while (peek() >= '0' && peek() <= '9') {
        const int digit = peek() - '0';
        if (d > (kMaxDim - digit) / 10) fail("shape", "dimension too large");  // checked before it can overflow
        d = d * 10 + digit;
        ++i_;
      }
      if (peek() == 'L') ++i_;  // Python 2's long literal
      dims.push_back(d);
      space();
      if (peek() == ',') {
        ++i_;
      } else if (peek() != ')') {
        fail("shape", "expected ',' or ')' in the tuple");
      }
    }
  }
  void skip_value(const std::string& key) {
    const char c = peek();
    if (c == '\'' || c == '"')
      (void)string_literal("a value");
    else if (c == '(')
      (void)tuple();
    else if (c == 'T' || c == 'F')
      (void)boolean("header");
    else
      fail("header", "cannot read the value of '" + printable(key, kNpyQuoteChars) + "'");
  }

  std::string_view s_;
  const std::string& origin_;
  size_t i_ = 0;
};

uint64_t le_uint(const std::string& b, size_t at, size_t n) {
  uint64_t v = 0;
  for (size_t k = 0; k < n; ++k) v |= uint64_t{static_cast<unsigned char>(b[at + k])} << (8 * k);
  return v;
}

}  // namespace

NpyArray parse_npy(const std::string& b, const std::string& origin) {
  if (b.size() < kMagicBytes + 2 || std::memcmp(b.data(), kMagic, kMagicBytes) != 0)
    throw InputError(origin, "header", "not a .npy file (no \\x93NUMPY magic)");
  const int major = static_cast<unsigned char>(b[6]), minor = static_cast<unsigned char>(b[7]);
  if (major < 1 || major > 3 || minor != 0)
    throw InputError(origin, "header",
                     "unsupported .npy format version " + std::to_string(major) + "." + std::to_string(minor) +
                         " (1.0, 2.0 and 3.0 are read)");
  const size_t len_bytes = major == 1 ? 2 : 4;
  const size_t start = kMagicBytes + 2 + len_bytes;
  if (b.size() < start) throw InputError(origin, "header", "truncated before the header length");
  const uint64_t header_len = le_uint(b, kMagicBytes + 2, len_bytes);
  if (header_len > b.size() - start)
    throw InputError(origin, "header",
                     "header length " + std::to_string(header_len) + " runs past the end of the file (" +
                         std::to_string(b.size()) + " bytes)");
  const Header h = HeaderParser(std::string_view(b).substr(start, header_len), origin).parse();

  size_t item = 0;
  if (h.descr == "<f8" || h.descr == ">f8")
    item = 8;
  else if (h.descr == "<f4" || h.descr == ">f4")
    item = 4;
  else
    throw InputError(origin, "descr",
                     "dtype '" + printable(h.descr, kNpyQuoteChars) + "' not supported (need float32 or float64)");
  const bool big_endian = h.descr[0] == '>';

  // The element count, checked so that count * item cannot overflow: a dimension of 0 makes it 0
  // whatever the others are.
  uint64_t count = 1;
  bool empty = false;
  for (const int64_t d : h.shape) empty = empty || d == 0;
  if (empty) {
    count = 0;
  } else {
    for (const int64_t d : h.shape) {
      if (count > std::numeric_limits<uint64_t>::max() / 8 / static_cast<uint64_t>(d))
        throw InputError(origin, "shape", "the product of the dimensions overflows");
      count *= static_cast<uint64_t>(d);
    }
  }
  const size_t data_start = start + static_cast<size_t>(header_len);
  const uint64_t need = count * item, have = b.size() - data_start;
  if (need != have)
    throw InputError(origin, "data", "expected " + std::to_string(need) + " bytes, file has " + std::to_string(have));

  // Each element from its bytes in the file's order, whatever the machine's.
  std::vector<double> values(static_cast<size_t>(count));
  const unsigned char* p = reinterpret_cast<const unsigned char*>(b.data()) + data_start;
  for (size_t e = 0; e < values.size(); ++e, p += item) {
    uint64_t bits = 0;
    for (size_t k = 0; k < item; ++k) bits |= uint64_t{p[big_endian ? item - 1 - k : k]} << (8 * k);
    if (item == 8) {
      double d;
      std::memcpy(&d, &bits, sizeof d);
      values[e] = d;
    } else {
      const auto u = static_cast<uint32_t>(bits);
      float f;
      std::memcpy(&f, &u, sizeof f);
      values[e] = f;
    }
  }

  NpyArray a;
  a.shape = h.shape;
  if (!h.fortran || a.shape.size() < 2 || values.empty()) {
    a.data = std::move(values);
    return a;
  }
  // Fortran order: the first index varies fastest. Walk the file's order with an index counter
  // that carries from the first dimension up, and place each element at its C-order offset.
  const size_t nd = a.shape.size();
  std::vector<size_t> c_stride(nd, 1);
  for (size_t k = nd - 1; k > 0; --k) c_stride[k - 1] = c_stride[k] * static_cast<size_t>(a.shape[k]);
  a.data.resize(values.size());
  std::vector<int64_t> idx(nd, 0);
  size_t offset = 0;
  for (const double v : values) {
    a.data[offset] = v;
    for (size_t k = 0; k < nd; ++k) {
      offset += c_stride[k];
      if (++idx[k] < a.shape[k]) break;
      offset -= c_stride[k] * static_cast<size_t>(a.shape[k]);
      idx[k] = 0;
    }
  }
  return a;
}

NpyArray read_npy(const std::string& path) { return parse_npy(read_file(path), path); }

}  // namespace ablenerf
