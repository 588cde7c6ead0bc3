#include "util/jpeg_codec.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <stdexcept>

// jpeglib.h is a C header that uses size_t and FILE without including their headers: after
// <cstddef> (via jpeg_codec.h) and <cstdio>.
#include <jpeglib.h>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

// libjpeg's error manager extended with a place to jump back to. libjpeg calls error_exit on an
// error and must never get control back (its default calls exit()), so jpeg_on_error formats the
// message and longjmps to jpeg_guarded, which throws. `pub` comes first: libjpeg only sees a
// jpeg_error_mgr*, which is cast back (a standard-layout struct and its first member share their
// address).
struct JpegErrorManager {
  jpeg_error_mgr pub;
  std::jmp_buf jump;
  bool warning = false;  // the jump came from a warning, not an error
  char message[JMSG_LENGTH_MAX] = {};
};

[[noreturn]] void jpeg_on_error(j_common_ptr cinfo) {
  auto* err = reinterpret_cast<JpegErrorManager*>(cinfo->err);
  (*cinfo->err->format_message)(cinfo, err->message);
  std::longjmp(err->jump, 1);
}

// Level -1 is a warning: corrupt entropy-coded data, extraneous bytes, or "Premature end of JPEG
// file", after which libjpeg would carry on and fill the rest of the image with grey. A training
// image with a grey band is worse than a refusal, so every warning stops the decode. Levels >= 0
// are trace messages (never shown).
void jpeg_on_message(j_common_ptr cinfo, int level) {
  if (level >= 0) return;
  reinterpret_cast<JpegErrorManager*>(cinfo->err)->warning = true;
  jpeg_on_error(cinfo);
}

// Opens `path` for reading with read_file's messages (util/fs.h): a missing file or a folder is an
// InputError naming it.
std::FILE* open_jpeg_file(const std::string& path) {
  const int fd = open_for_reading(path);
  std::FILE* f = ::fdopen(fd, "rb");
  if (!f) {
    const int e = errno;
    ::close(fd);
    throw InputError(path, "", std::string("cannot read: ") + std::strerror(e));
  }
  return f;
}

// One decompression: the open file, libjpeg's object and its error manager, released on every
// path by the destructor. The object starts zeroed, so jpeg_destroy_decompress is safe even when
// jpeg_create_decompress never ran or failed half-way (it frees only what `mem` holds).
struct JpegSession {
  const std::string& path;
  std::FILE* file;
  JpegErrorManager err;
  jpeg_decompress_struct cinfo;

  explicit JpegSession(const std::string& p) : path(p), file(open_jpeg_file(p)) {
    std::memset(&cinfo, 0, sizeof(cinfo));
    cinfo.err = jpeg_std_error(&err.pub);
    err.pub.error_exit = jpeg_on_error;
    err.pub.emit_message = jpeg_on_message;
  }
  ~JpegSession() {
    jpeg_destroy_decompress(&cinfo);
    std::fclose(file);
  }
  JpegSession(const JpegSession&) = delete;
  JpegSession& operator=(const JpegSession&) = delete;
};

// Runs `step`, a lambda that only calls libjpeg, and turns a libjpeg error or warning into an
// InputError naming the file. longjmp skips the frames between libjpeg's callback and this one
// without running destructors, so `step` must own no C++ object with one; the state it changes
// lives in the session (memory, not registers), which keeps its value across the jump.
template <class Step>
void jpeg_guarded(JpegSession& s, const Step& step) {
  if (setjmp(s.err.jump) == 0) {
    step();
    return;
  }
  const char* kind = s.err.warning ? "truncated or corrupt JPEG: " : "not a readable JPEG: ";
  throw InputError(s.path, "", kind + std::string(s.err.message));
}

// Reads the header (saving APP1 segments for the EXIF orientation when `save_app1`) and refuses
// what the header alone rules out: colour spaces other than grey/YCbCr/RGB and oversized images.
void read_jpeg_header(JpegSession& s, bool save_app1) {
  jpeg_decompress_struct& c = s.cinfo;
  jpeg_guarded(s, [&] {
    jpeg_create_decompress(&c);
    jpeg_stdio_src(&c, s.file);
    if (save_app1) jpeg_save_markers(&c, JPEG_APP0 + 1, 0xFFFF);
    jpeg_read_header(&c, TRUE);  // TRUE: a tables-only stream is an error
  });
  switch (c.jpeg_color_space) {
    case JCS_GRAYSCALE:
    case JCS_YCbCr:
    case JCS_RGB: break;
    case JCS_CMYK:
    case JCS_YCCK: throw InputError(s.path, "colour space", "CMYK/YCCK JPEG is not supported (convert it to RGB)");
    default:
      throw InputError(s.path, "colour space",
                       "JPEG with " + std::to_string(c.num_components) +
                           " colour components is not supported (expected greyscale or RGB/YCbCr)");
  }
  // libjpeg itself refuses 0 and anything above 65500 per side.
  const int64_t w = c.image_width, h = c.image_height;
  if (w * h > kMaxImagePixels)
    throw InputError(s.path, "",
                     "unsupported JPEG size " + std::to_string(w) + "x" + std::to_string(h) + " (more than " +
                         std::to_string(kMaxImagePixels) + " pixels)");
}

// The orientation of the first saved APP1 segment that is EXIF (XMP also lives in APP1).
int saved_exif_orientation(const jpeg_decompress_struct& c) {
  for (jpeg_saved_marker_ptr m = c.marker_list; m != nullptr; m = m->next) {
    if (m->marker == JPEG_APP0 + 1 && m->data_length >= 6 && std::memcmp(m->data, "Exif\0\0", 6) == 0)
      return parse_exif_orientation(m->data, m->data_length);
  }
  return 1;
}

uint32_t exif_u16(const uint8_t* p, bool little) {
  return little ? uint32_t(p[0]) | uint32_t(p[1]) << 8 : uint32_t(p[0]) << 8 | uint32_t(p[1]);
}

uint32_t exif_u32(const uint8_t* p, bool little) {
  return little ? exif_u16(p, true) | exif_u16(p + 2, true) << 16 : exif_u16(p, false) << 16 | exif_u16(p + 2, false);
}

}  // namespace

int parse_exif_orientation(const uint8_t* app1, size_t size) {
  // "Exif\0\0" then the 8-byte TIFF header; offsets inside are relative to the TIFF header.
  if (app1 == nullptr || size < 6 + 8 || std::memcmp(app1, "Exif\0\0", 6) != 0) return 1;
  const uint8_t* tiff = app1 + 6;
  const uint64_t n = size - 6;  // 64-bit: offset + count arithmetic below cannot wrap
  bool little;
  if (tiff[0] == 'I' && tiff[1] == 'I') {
    little = true;
  } else if (tiff[0] == 'M' && tiff[1] == 'M') {
    little = false;
  } else {
    return 1;
  }
  if (exif_u16(tiff + 2, little) != 42) return 1;
  const uint64_t ifd = exif_u32(tiff + 4, little);
  if (ifd < 8 || ifd + 2 > n) return 1;  // IFD0 must follow the header and hold its entry count
  const uint64_t entries = exif_u16(tiff + ifd, little);
  for (uint64_t i = 0; i < entries; ++i) {
    const uint64_t e = ifd + 2 + 12 * i;  // tag u16, type u16, count u32, value u32
    if (e + 12 > n) return 1;
    if (exif_u16(tiff + e, little) != 0x0112) continue;
    const uint32_t type = exif_u16(tiff + e + 2, little), count = exif_u32(tiff + e + 4, little);
    if (type != 3 || count != 1) return 1;  // must be one SHORT, stored in the value field's first 2 bytes
    const uint32_t v = exif_u16(tiff + e + 8, little);
    return v >= 1 && v <= 8 ? static_cast<int>(v) : 1;
  }
  return 1;
}

std::pair<int, int> jpeg_size(const std::string& path) {
  JpegSession s(path);
  read_jpeg_header(s, false);
  return {static_cast<int>(s.cinfo.image_height), static_cast<int>(s.cinfo.image_width)};
}

Image8 decode_jpeg_file(const std::string& path, int* exif_orientation, int reduce, std::pair<int, int>* stored_size) {
  if (reduce != 1 && reduce != 2 && reduce != 4 && reduce != 8)
    throw std::invalid_argument("decode_jpeg_file: reduce must be 1, 2, 4 or 8");
  JpegSession s(path);
  read_jpeg_header(s, exif_orientation != nullptr);
  jpeg_decompress_struct& c = s.cinfo;
  if (exif_orientation) *exif_orientation = saved_exif_orientation(c);
  if (stored_size) *stored_size = {static_cast<int>(c.image_height), static_cast<int>(c.image_width)};
  // libjpeg converts YCbCr (and RGB) to RGB with upsampled chroma ("fancy" triangle upsampling and
  // the accurate integer IDCT, its defaults).
  c.out_color_space = c.jpeg_color_space == JCS_GRAYSCALE ? JCS_GRAYSCALE : JCS_RGB;
  c.scale_num = 1;
  c.scale_denom = static_cast<unsigned int>(reduce);
  jpeg_guarded(s, [&] { jpeg_start_decompress(&c); });

  Image8 out;
  out.width = static_cast<int>(c.output_width);
  out.height = static_cast<int>(c.output_height);
  out.channels = c.output_components;
  const size_t row_bytes = static_cast<size_t>(out.width) * static_cast<size_t>(out.channels);
  // Reserved (untouched address space) and grown a batch of rows at a time, so a small truncated
  // file that claims a huge size is refused before most of the buffer is ever written.
  out.pixels.reserve(row_bytes * static_cast<size_t>(out.height));
  constexpr JDIMENSION kRowsPerCall = 16;
  JSAMPROW rows[kRowsPerCall];
  while (c.output_scanline < c.output_height) {
    const JDIMENSION done = c.output_scanline;
    const JDIMENSION n = std::min(kRowsPerCall, c.output_height - done);
    out.pixels.resize(row_bytes * (done + n));
    for (JDIMENSION k = 0; k < n; ++k) rows[k] = out.pixels.data() + row_bytes * (done + k);
    jpeg_guarded(s, [&] { jpeg_read_scanlines(&c, rows, n); });
  }
  // Reads up to the EOI marker: a file cut after the last row is refused too.
  jpeg_guarded(s, [&] { jpeg_finish_decompress(&c); });
  return out;
}

void apply_exif_orientation(Image8& im, int orientation) {
  if (orientation < 2 || orientation > 8) return;
  const int64_t h = im.height, w = im.width, ch = im.channels;
  if (h < 0 || w < 0 || ch < 0 || im.pixels.size() != static_cast<size_t>(h * w * ch))
    throw std::invalid_argument("apply_exif_orientation: pixel buffer size is not height * width * channels");
  // The source pixel of D(r, c) is S's pixel number origin + r * dr + c * dc (see the header).
  int64_t origin = 0, dr = 0, dc = 0;
  switch (orientation) {
    case 2: origin = w - 1, dr = w, dc = -1; break;
    case 3: origin = h * w - 1, dr = -w, dc = -1; break;
    case 4: origin = (h - 1) * w, dr = -w, dc = 1; break;
    case 5: origin = 0, dr = 1, dc = w; break;
    case 6: origin = (h - 1) * w, dr = 1, dc = -w; break;
    case 7: origin = h * w - 1, dr = -1, dc = -w; break;
    case 8: origin = w - 1, dr = -1, dc = w; break;
  }
  const bool swap = orientation >= 5;
  const int64_t out_h = swap ? w : h, out_w = swap ? h : w;
  if (h == 0 || w == 0) {
    im.height = static_cast<int>(out_h);
    im.width = static_cast<int>(out_w);
    return;
  }
  std::vector<uint8_t> out(im.pixels.size());
  const uint8_t* src = im.pixels.data();
  uint8_t* dst = out.data();
  for (int64_t r = 0; r < out_h; ++r) {
    int64_t s = origin + r * dr;
    for (int64_t c = 0; c < out_w; ++c, s += dc, dst += ch) std::memcpy(dst, src + s * ch, static_cast<size_t>(ch));
  }
  im.pixels.swap(out);
  im.height = static_cast<int>(out_h);
  im.width = static_cast<int>(out_w);
}

}  // namespace ablenerf
