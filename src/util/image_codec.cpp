#include "util/image_codec.h"

#include <jpeglib.h>

#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <memory>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

const unsigned char kPngMagic[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};

bool is_png(const std::string& b) { return b.size() >= 8 && std::memcmp(b.data(), kPngMagic, 8) == 0; }
bool is_jpeg(const std::string& b) {
  return b.size() >= 3 && static_cast<unsigned char>(b[0]) == 0xFF && static_cast<unsigned char>(b[1]) == 0xD8 &&
         static_cast<unsigned char>(b[2]) == 0xFF;
}

std::string head_of(const std::string& path, size_t n) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) throw InputError(path, "", "cannot open image");
  std::string s(n, '\0');
  const size_t got = std::fread(s.data(), 1, n, f);
  std::fclose(f);
  s.resize(got);
  return s;
}

// libjpeg reports errors through a callback that must not return: longjmp back to the caller,
// which turns the message into an InputError. Warnings (e.g. "Premature end of JPEG file", after
// which libjpeg fills the rest of the image with grey) are errors here too.
struct JpegError {
  jpeg_error_mgr mgr;
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX];
};

void on_error(j_common_ptr cinfo) {
  auto* e = reinterpret_cast<JpegError*>(cinfo->err);
  (*cinfo->err->format_message)(cinfo, e->message);
  std::longjmp(e->jump, 1);
}

void on_message(j_common_ptr cinfo, int level) {
  if (level < 0) on_error(cinfo);  // a warning: corrupt or truncated data
}

int read_u16(const unsigned char* p, bool le) { return le ? p[0] | (p[1] << 8) : (p[0] << 8) | p[1]; }
uint32_t read_u32(const unsigned char* p, bool le) {
  return le ? (uint32_t(p[0]) | uint32_t(p[1]) << 8 | uint32_t(p[2]) << 16 | uint32_t(p[3]) << 24)
            : (uint32_t(p[0]) << 24 | uint32_t(p[1]) << 16 | uint32_t(p[2]) << 8 | uint32_t(p[3]));
}

// Decodes (or, with header_only, reads the size of) a JPEG in memory. All of libjpeg's state lives
// in this frame; no C++ object with a destructor is live across setjmp.
DecodedImage run_jpeg(const std::string& bytes, const std::string& origin, bool header_only) {
  DecodedImage out;
  jpeg_decompress_struct cinfo;
  JpegError err;
  cinfo.err = jpeg_std_error(&err.mgr);
  err.mgr.error_exit = on_error;
  err.mgr.emit_message = on_message;
  std::string failure;
  std::vector<uint8_t>* pixels = &out.image.pixels;
  if (setjmp(err.jump)) {
    failure = err.message;
    jpeg_destroy_decompress(&cinfo);
    throw InputError(origin, "", "truncated or corrupt JPEG: " + failure);
  }
  jpeg_create_decompress(&cinfo);
  jpeg_mem_src(&cinfo, reinterpret_cast<const unsigned char*>(bytes.data()), static_cast<unsigned long>(bytes.size()));
  jpeg_save_markers(&cinfo, JPEG_APP0 + 1, 0xFFFF);
  jpeg_read_header(&cinfo, TRUE);
  if (cinfo.jpeg_color_space == JCS_CMYK || cinfo.jpeg_color_space == JCS_YCCK) {
    jpeg_destroy_decompress(&cinfo);
    throw InputError(origin, "colour space", "CMYK/YCCK JPEG is not supported (convert it to RGB)");
  }
  for (jpeg_saved_marker_ptr m = cinfo.marker_list; m; m = m->next)
    if (m->marker == JPEG_APP0 + 1) {
      const int o = exif_orientation(std::string(reinterpret_cast<const char*>(m->data), m->data_length));
      if (o != 1) out.exif_orientation = o;
    }
  const int64_t w = cinfo.image_width, h = cinfo.image_height;
  if (w <= 0 || h <= 0 || w * h > kMaxPngPixels) {
    jpeg_destroy_decompress(&cinfo);
    throw InputError(origin, "", "unsupported JPEG size " + std::to_string(w) + "x" + std::to_string(h));
  }
  out.image.width = static_cast<int>(w);
  out.image.height = static_cast<int>(h);
  if (header_only) {
    jpeg_destroy_decompress(&cinfo);
    return out;
  }
  const bool grey = cinfo.jpeg_color_space == JCS_GRAYSCALE;
  cinfo.out_color_space = grey ? JCS_GRAYSCALE : JCS_RGB;
  jpeg_start_decompress(&cinfo);
  const int c = cinfo.output_components;
  out.image.channels = c;
  pixels->resize(static_cast<size_t>(w * h * c));
  while (cinfo.output_scanline < cinfo.output_height) {
    JSAMPROW row = pixels->data() + static_cast<size_t>(cinfo.output_scanline) * static_cast<size_t>(w * c);
    jpeg_read_scanlines(&cinfo, &row, 1);
  }
  jpeg_finish_decompress(&cinfo);
  jpeg_destroy_decompress(&cinfo);
  return out;
}

}  // namespace

int exif_orientation(const std::string& app1) {
  const auto* p = reinterpret_cast<const unsigned char*>(app1.data());
  const size_t n = app1.size();
  if (n < 14 || std::memcmp(p, "Exif\0\0", 6) != 0) return 1;
  const unsigned char* t = p + 6;  // TIFF header
  const size_t tn = n - 6;
  bool le;
  if (t[0] == 'I' && t[1] == 'I') le = true;
  else if (t[0] == 'M' && t[1] == 'M') le = false;
  else return 1;
  const uint32_t ifd = read_u32(t + 4, le);
  if (ifd > tn || tn - ifd < 2) return 1;
  const int count = read_u16(t + ifd, le);
  for (int i = 0; i < count; ++i) {
    const size_t e = ifd + 2 + static_cast<size_t>(i) * 12;
    if (e + 12 > tn) return 1;
    if (read_u16(t + e, le) == 0x0112) {
      const int v = read_u16(t + e + 8, le);
      return v >= 1 && v <= 8 ? v : 1;
    }
  }
  return 1;
}

DecodedImage decode_jpeg_bytes(const std::string& bytes, const std::string& origin) {
  return run_jpeg(bytes, origin, false);
}

DecodedImage decode_image_file(const std::string& path) {
  const std::string head = head_of(path, 8);
  if (is_png(head)) return {decode_png_file(path), 1};
  if (is_jpeg(head)) return run_jpeg(read_file(path), path, false);
  throw InputError(path, "", "not a PNG or JPEG image");
}

std::pair<int, int> image_size(const std::string& path) {
  const std::string head = head_of(path, 8);
  if (is_png(head)) return png_size(path);
  if (is_jpeg(head)) {
    // The header is near the start; a whole small file is read only when it is short.
    const DecodedImage d = run_jpeg(read_file(path), path, true);
    return {d.image.height, d.image.width};
  }
  throw InputError(path, "", "not a PNG or JPEG image");
}

}  // namespace ablenerf
