#pragma once
// A JPEG encoder for the tests (libjpeg's compressor: independent of the decoder under test) and a
// hand-built EXIF APP1 payload carrying an orientation.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include <jpeglib.h>  // after <cstdio>: it uses FILE and size_t

namespace ablenerf::test {

// How the test encodes: sampling factors of the first component (the others stay 1x1), so
// 1x1 = 4:4:4, 2x1 = 4:2:2, 2x2 = 4:2:0, 4x1 = 4:1:1.
struct JpegOptions {
  int luma_h = 1, luma_v = 1;
  bool progressive = false;
  J_COLOR_SPACE in_space = JCS_RGB;  // JCS_GRAYSCALE (1 component), JCS_RGB (3), JCS_CMYK (4)
  std::string app1;                  // payload of an APP1 segment written after the header, "" for none
};

// The encoder's errors are the test's own bugs: report and stop.
[[noreturn]] inline void encoder_error(j_common_ptr cinfo) {
  char msg[JMSG_LENGTH_MAX];
  (*cinfo->err->format_message)(cinfo, msg);
  std::fprintf(stderr, "test JPEG encoder: %s\n", msg);
  std::abort();
}

// Encodes row-major (h, w, components) bytes as a quality-100 JPEG with libjpeg's compressor.
inline std::string encode_jpeg(const std::vector<uint8_t>& pixels, int w, int h, const JpegOptions& o) {
  jpeg_compress_struct c;
  jpeg_error_mgr err;
  c.err = jpeg_std_error(&err);
  err.error_exit = encoder_error;
  jpeg_create_compress(&c);
  unsigned char* buf = nullptr;
  unsigned long size = 0;
  jpeg_mem_dest(&c, &buf, &size);
  c.image_width = static_cast<JDIMENSION>(w);
  c.image_height = static_cast<JDIMENSION>(h);
  c.in_color_space = o.in_space;
  c.input_components = o.in_space == JCS_GRAYSCALE ? 1 : o.in_space == JCS_CMYK ? 4 : 3;
  jpeg_set_defaults(&c);
  jpeg_set_quality(&c, 100, TRUE);  // every quantiser 1: what is lost is rounding and chroma sampling
  c.comp_info[0].h_samp_factor = o.luma_h;
  c.comp_info[0].v_samp_factor = o.luma_v;
  for (int i = 1; i < c.num_components; ++i) c.comp_info[i].h_samp_factor = c.comp_info[i].v_samp_factor = 1;
  if (o.progressive) jpeg_simple_progression(&c);
  jpeg_start_compress(&c, TRUE);
  if (!o.app1.empty())
    jpeg_write_marker(&c, JPEG_APP0 + 1, reinterpret_cast<const JOCTET*>(o.app1.data()),
                      static_cast<unsigned>(o.app1.size()));
  const size_t row_bytes = static_cast<size_t>(w) * c.input_components;
  while (c.next_scanline < c.image_height) {
    JSAMPROW row = const_cast<uint8_t*>(pixels.data()) + row_bytes * c.next_scanline;
    jpeg_write_scanlines(&c, &row, 1);
  }
  jpeg_finish_compress(&c);
  jpeg_destroy_compress(&c);
  std::string out(reinterpret_cast<const char*>(buf), size);
  std::free(buf);
  return out;
}

// A hand-built APP1 payload: "Exif\0\0", a TIFF header in the given byte order, IFD0 at offset 8
// with two entries, Make (0x010F, ASCII, pointing past IFD0) before Orientation (0x0112, one
// SHORT), then "next IFD" 0 and Make's string.
inline std::string exif_payload(bool little, int orientation) {
  std::string s("Exif\0\0", 6);
  const auto u16 = [&](unsigned v) {
    const char b[2] = {char(v & 0xFF), char(v >> 8)};
    s += little ? std::string{b[0], b[1]} : std::string{b[1], b[0]};
  };
  const auto u32 = [&](uint32_t v) {
    if (little) {
      u16(v & 0xFFFF), u16(v >> 16);
    } else {
      u16(v >> 16), u16(v & 0xFFFF);
    }
  };
  s += little ? "II" : "MM";
  u16(42);
  u32(8);                                                // IFD0 right after the header
  u16(2);                                                // two entries
  u16(0x010F), u16(2), u32(6), u32(8 + 2 + 2 * 12 + 4);  // Make: 6 ASCII bytes after IFD0
  u16(0x0112), u16(3), u32(1);                           // Orientation: one SHORT ...
  u16(static_cast<unsigned>(orientation)), u16(0);       // ... left-justified in the value field
  u32(0);                                                // no IFD1
  s += std::string("Phone\0", 6);
  return s;
}

}  // namespace ablenerf::test
