// The PNG/JPEG decoder (util/image_codec.h, util/jpeg_codec.h), torch-free. Every JPEG is made
// here by libjpeg's own compressor (quality 100, chosen sampling factors, optional progressive
// scans, CMYK, a hand-built EXIF APP1 segment), so the references are the pixels that went in and
// hand-written layouts, never the decoder's own output.
#include <gtest/gtest.h>
#include <stdlib.h>  // mkdtemp

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

// A C header that uses size_t and FILE without including their headers: after <cstddef>, <cstdio>.

#include "jpeg_writer.h"
#include "util/errors.h"
#include "util/image_codec.h"
#include "util/jpeg_codec.h"
#include "util/png_codec.h"

using namespace ablenerf;
using namespace ablenerf::test;
namespace fs = std::filesystem;

namespace {

// A fresh folder under the system temp dir, removed with everything in it at the end of the test.
class ScratchDir {
 public:
  ScratchDir() {
    std::string tmpl = (fs::temp_directory_path() / "ablenerf_image_codec_XXXXXX").string();
    if (::mkdtemp(tmpl.data()) == nullptr) std::abort();
    path_ = tmpl;
  }
  ~ScratchDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  std::string operator/(const std::string& name) const { return path_ + "/" + name; }

 private:
  std::string path_;
};

void write_bytes(const std::string& path, const std::string& bytes) {
  std::ofstream f(path, std::ios::binary | std::ios::trunc);
  f.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  ASSERT_TRUE(f.good()) << path;
}

// A smooth image: each channel a different linear ramp (slopes of 1.7 to 4.4 levels per pixel on
// 61 x 45), no edges. 61 and 45 are not multiples of any MCU size, so partial blocks are decoded.
constexpr int kW = 61, kH = 45;
std::vector<uint8_t> smooth_rgb(int w, int h) {
  std::vector<uint8_t> p(static_cast<size_t>(w) * h * 3);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      uint8_t* q = &p[(static_cast<size_t>(y) * w + x) * 3];
      q[0] = static_cast<uint8_t>(20 + 200 * x / (w - 1));
      q[1] = static_cast<uint8_t>(230 - 180 * y / (h - 1));
      q[2] = static_cast<uint8_t>(40 + 100 * (x + y) / (w + h - 2));
    }
  return p;
}

std::vector<uint8_t> smooth_grey(int w, int h) {
  std::vector<uint8_t> p(static_cast<size_t>(w) * h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) p[static_cast<size_t>(y) * w + x] = static_cast<uint8_t>(10 + 3 * x + 2 * y);
  return p;
}

int max_abs_diff(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b) {
  EXPECT_EQ(a.size(), b.size());
  int m = 0;
  for (size_t i = 0; i < std::min(a.size(), b.size()); ++i) m = std::max(m, std::abs(int(a[i]) - int(b[i])));
  return m;
}

double mean_abs_diff(const std::vector<uint8_t>& a, const std::vector<uint8_t>& b) {
  double s = 0;
  for (size_t i = 0; i < std::min(a.size(), b.size()); ++i) s += std::abs(int(a[i]) - int(b[i]));
  return a.empty() ? 0.0 : s / static_cast<double>(a.size());
}

}  // namespace

TEST(JpegDecode, SmoothRgbMatchesTheOriginalForEverySubsampling) {
  ScratchDir dir;
  const auto rgb = smooth_rgb(kW, kH);
  // Bounds on the largest and the mean error per channel (levels of 255; measured with
  // libjpeg-turbo 2.1: max 3/3/3/6, mean 0.39/0.47/0.47/1.30). 4:4:4 at quality 100 loses only the
  // rounding of YCbCr to 8 bits and of the integer IDCT, about half a level each, amplified by up to
  // 1.8 in the YCbCr -> RGB matrix: 3. 4:2:2 and 4:2:0 average chroma over 2 (4) pixels and
  // upsample it linearly ("fancy" upsampling), exact for a ramp except at the borders, where it is
  // off by about half a pixel's chroma change (Cr changes by 1.6 levels per pixel here, x1.4 in R):
  // 1 more, 4. 4:1:1 chroma is upsampled by replication (libjpeg's linear upsampling covers only 2x
  // factors), off by up to 1.5 pixels' chroma change everywhere (~2.4 levels of Cr, 3.4 of R) on top
  // of the rounding: 8, and a larger mean.
  struct Case {
    const char* name;
    int h, v, max_err;
    double max_mean;
  };
  for (const Case& k : {Case{"444", 1, 1, 3, 0.75}, Case{"422", 2, 1, 4, 0.75}, Case{"420", 2, 2, 4, 0.75},
                        Case{"411", 4, 1, 8, 2.0}}) {
    SCOPED_TRACE(k.name);
    JpegOptions o;
    o.luma_h = k.h, o.luma_v = k.v;
    const std::string path = dir / (std::string(k.name) + ".jpg");
    write_bytes(path, encode_jpeg(rgb, kW, kH, o));
    int orientation = 0;
    const Image8 im = decode_jpeg_file(path, &orientation);
    EXPECT_EQ(im.width, kW);
    EXPECT_EQ(im.height, kH);
    ASSERT_EQ(im.channels, 3);
    ASSERT_EQ(im.pixels.size(), rgb.size());
    EXPECT_EQ(orientation, 1);  // no EXIF
    EXPECT_LE(max_abs_diff(im.pixels, rgb), k.max_err);
    EXPECT_LT(mean_abs_diff(im.pixels, rgb), k.max_mean);
    // The dispatcher gives the same pixels.
    const DecodedImage d = decode_image_file(path);
    EXPECT_EQ(d.image.pixels, im.pixels);
    EXPECT_EQ(d.exif_orientation, 1);
  }
}

TEST(JpegDecode, GreyscaleIsOneChannel) {
  ScratchDir dir;
  const auto grey = smooth_grey(kW, kH);
  JpegOptions o;
  o.in_space = JCS_GRAYSCALE;
  write_bytes(dir / "grey.jpg", encode_jpeg(grey, kW, kH, o));
  const Image8 im = decode_jpeg_file(dir / "grey.jpg");
  ASSERT_EQ(im.channels, 1);
  EXPECT_EQ(im.width, kW);
  EXPECT_EQ(im.height, kH);
  EXPECT_LE(max_abs_diff(im.pixels, grey), 1);  // quality 100, no colour conversion: IDCT rounding only
}

TEST(JpegDecode, ProgressiveEqualsItsBaselineTwin) {
  ScratchDir dir;
  const auto rgb = smooth_rgb(kW, kH);
  for (int sub : {1, 2}) {
    JpegOptions o;
    o.luma_h = o.luma_v = sub;
    write_bytes(dir / "base.jpg", encode_jpeg(rgb, kW, kH, o));
    o.progressive = true;
    const std::string prog = encode_jpeg(rgb, kW, kH, o);
    // Really progressive: SOF2, not SOF0.
    ASSERT_NE(prog.find("\xFF\xC2", 0, 2), std::string::npos);
    write_bytes(dir / "prog.jpg", prog);
    const Image8 base = decode_jpeg_file(dir / "base.jpg"), p = decode_jpeg_file(dir / "prog.jpg");
    ASSERT_EQ(p.width, kW);
    ASSERT_EQ(p.height, kH);
    EXPECT_LE(max_abs_diff(p.pixels, base.pixels), 1) << "sampling " << sub;
  }
}

TEST(JpegExif, OrientationFromBothByteOrders) {
  ScratchDir dir;
  const auto rgb = smooth_rgb(16, 8);
  for (bool little : {true, false}) {
    for (int want : {6, 3}) {
      SCOPED_TRACE(std::string(little ? "II " : "MM ") + std::to_string(want));
      JpegOptions o;
      o.app1 = exif_payload(little, want);
      const std::string path = dir / "exif.jpg";
      write_bytes(path, encode_jpeg(rgb, 16, 8, o));
      int orientation = 0;
      const Image8 im = decode_jpeg_file(path, &orientation);
      EXPECT_EQ(orientation, want);
      EXPECT_EQ(im.width, 16);  // stored, not rotated
      EXPECT_EQ(im.height, 8);
      EXPECT_EQ(decode_image_file(path).exif_orientation, want);
      EXPECT_EQ(image_size(path), std::make_pair(8, 16));
    }
  }
}

TEST(JpegExif, MalformedExifReportsOneAndStillDecodes) {
  ScratchDir dir;
  const auto rgb = smooth_rgb(16, 8);
  std::string past_end = exif_payload(true, 6);
  past_end[6 + 4] = '\x00', past_end[6 + 5] = '\x10';  // IFD0 offset 0x1000: past the segment's end
  std::string bad_order = exif_payload(true, 6);
  bad_order[6] = 'X';
  std::string bad_value = exif_payload(false, 9);  // not 1..8
  std::string too_many = exif_payload(true, 6);
  too_many.resize(6 + 8 + 2 + 12);  // Orientation's entry is cut off ...
  too_many[6 + 8] = '\x50';         // ... and 80 entries are claimed
  for (const std::string& app1 : {past_end, bad_order, bad_value, too_many, std::string("Exif\0\0MM", 8)}) {
    JpegOptions o;
    o.app1 = app1;
    write_bytes(dir / "bad_exif.jpg", encode_jpeg(rgb, 16, 8, o));
    int orientation = 0;
    Image8 im;
    ASSERT_NO_THROW(im = decode_jpeg_file(dir / "bad_exif.jpg", &orientation));
    EXPECT_EQ(orientation, 1);
    EXPECT_EQ(im.width, 16);
    EXPECT_EQ(im.height, 8);
  }
}

TEST(JpegExif, ParserNeverReadsPastTheSegment) {
  // Every prefix of a valid payload, copied to a buffer of exactly that size: the orientation
  // appears only once its whole 12-byte entry is inside, and nothing before that reads further.
  const std::string full = exif_payload(false, 8);
  const size_t entry_end = 6 + 8 + 2 + 2 * 12;
  for (size_t n = 0; n <= full.size(); ++n) {
    const std::vector<uint8_t> prefix(full.begin(), full.begin() + static_cast<std::ptrdiff_t>(n));
    EXPECT_EQ(parse_exif_orientation(prefix.data(), prefix.size()), n >= entry_end ? 8 : 1) << n;
  }
  EXPECT_EQ(parse_exif_orientation(nullptr, 0), 1);
  // Orientation stored as a LONG (type 4) is not EXIF's SHORT: ignored.
  std::string as_long = exif_payload(true, 6);
  as_long[6 + 8 + 2 + 12 + 2] = 4;
  EXPECT_EQ(parse_exif_orientation(reinterpret_cast<const uint8_t*>(as_long.data()), as_long.size()), 1);
}

TEST(ExifOrientation, AllEightOnATwoByThreeImage) {
  // Stored (H 2 x W 3):   1 2 3
  //                       4 5 6
  // Expected layouts written out by hand from the EXIF definitions in jpeg_codec.h.
  struct Case {
    int orientation, h, w;
    std::vector<int> layout;
  };
  const std::vector<Case> cases = {
      {1, 2, 3, {1, 2, 3, 4, 5, 6}},  // unchanged
      {2, 2, 3, {3, 2, 1, 6, 5, 4}},  // mirrored left-right
      {3, 2, 3, {6, 5, 4, 3, 2, 1}},  // rotated 180
      {4, 2, 3, {4, 5, 6, 1, 2, 3}},  // mirrored top-bottom
      {5, 3, 2, {1, 4, 2, 5, 3, 6}},  // transposed
      {6, 3, 2, {4, 1, 5, 2, 6, 3}},  // rotated 90 clockwise: the left column, bottom up, on top
      {7, 3, 2, {6, 3, 5, 2, 4, 1}},  // transverse
      {8, 3, 2, {3, 6, 2, 5, 1, 4}},  // rotated 90 counter-clockwise: the right column on top
      {0, 2, 3, {1, 2, 3, 4, 5, 6}},  // not an orientation: unchanged
      {9, 2, 3, {1, 2, 3, 4, 5, 6}},
  };
  for (const int channels : {1, 3}) {
    for (const Case& k : cases) {
      SCOPED_TRACE("orientation " + std::to_string(k.orientation) + ", channels " + std::to_string(channels));
      // Pixel v has the channel values v, v + 10, v + 20.
      const auto make = [&](int h, int w, const std::vector<int>& layout) {
        Image8 im;
        im.height = h, im.width = w, im.channels = channels;
        for (int v : layout)
          for (int c = 0; c < channels; ++c) im.pixels.push_back(static_cast<uint8_t>(v + 10 * c));
        return im;
      };
      Image8 im = make(2, 3, {1, 2, 3, 4, 5, 6});
      const Image8 want = make(k.h, k.w, k.layout);
      apply_exif_orientation(im, k.orientation);
      EXPECT_EQ(im.height, want.height);
      EXPECT_EQ(im.width, want.width);
      EXPECT_EQ(im.channels, channels);
      EXPECT_EQ(im.pixels, want.pixels);
    }
  }
  Image8 broken;
  broken.height = 2, broken.width = 2, broken.channels = 3;
  broken.pixels.resize(5);
  EXPECT_THROW(apply_exif_orientation(broken, 6), std::invalid_argument);
}

TEST(JpegRefusals, TruncatedFilesAreRefusedNotPaddedWithGrey) {
  ScratchDir dir;
  const auto rgb = smooth_rgb(kW, kH);
  for (bool progressive : {false, true}) {
    JpegOptions o;
    o.luma_h = o.luma_v = 2;
    o.progressive = progressive;
    const std::string full = encode_jpeg(rgb, kW, kH, o);
    // Half the file (inside the entropy-coded data), and the whole file less its EOI marker.
    for (size_t keep : {full.size() / 2, full.size() - 2}) {
      SCOPED_TRACE(std::string(progressive ? "progressive" : "baseline") + " " + std::to_string(keep));
      const std::string path = dir / "cut.jpg";
      write_bytes(path, full.substr(0, keep));
      try {
        decode_image_file(path);
        ADD_FAILURE() << "a truncated JPEG was decoded";
      } catch (const InputError& e) {
        EXPECT_EQ(e.file(), path);
        EXPECT_NE(std::string(e.what()).find("truncated or corrupt JPEG"), std::string::npos) << e.what();
      }
      EXPECT_EQ(image_size(path), std::make_pair(kH, kW));  // the header alone is intact
    }
  }
}

TEST(JpegRefusals, CmykIsRefusedNamingTheColourSpace) {
  ScratchDir dir;
  std::vector<uint8_t> cmyk(16 * 8 * 4, 0x40);
  JpegOptions o;
  o.in_space = JCS_CMYK;
  const std::string path = dir / "cmyk.jpg";
  write_bytes(path, encode_jpeg(cmyk, 16, 8, o));
  for (int call = 0; call < 3; ++call) {
    try {
      if (call == 0) decode_image_file(path);
      if (call == 1) image_size(path);
      if (call == 2) decode_jpeg_file(path);
      ADD_FAILURE() << "a CMYK JPEG was accepted (call " << call << ")";
    } catch (const InputError& e) {
      EXPECT_EQ(e.field(), "colour space");
      EXPECT_NE(std::string(e.what()).find("CMYK/YCCK JPEG is not supported"), std::string::npos) << e.what();
    }
  }
}

TEST(JpegRefusals, GarbageAndOversizedHeaders) {
  ScratchDir dir;
  // JPEG magic, then pseudo-random bytes (fixed LCG): libjpeg's error becomes an InputError.
  std::string junk = "\xFF\xD8\xFF";
  uint32_t x = 12345;
  for (int i = 0; i < 3000; ++i) junk += static_cast<char>((x = x * 1664525u + 1013904223u) >> 24);
  write_bytes(dir / "junk.jpg", junk);
  EXPECT_THROW(decode_image_file(dir / "junk.jpg"), InputError);
  EXPECT_THROW(image_size(dir / "junk.jpg"), InputError);
  EXPECT_THROW(decode_jpeg_file(dir / "junk.jpg"), InputError);

  // A valid file whose SOF0 claims 20000 x 20000 (4e8 pixels > kMaxImagePixels): refused from the
  // header, before any pixel memory is allocated.
  std::string big = encode_jpeg(smooth_rgb(16, 16), 16, 16, JpegOptions());
  const size_t sof = big.find("\xFF\xC0", 0, 2);
  ASSERT_NE(sof, std::string::npos);
  for (size_t k : {sof + 5, sof + 7}) big[k] = '\x4E', big[k + 1] = '\x20';  // height, width = 20000
  write_bytes(dir / "big.jpg", big);
  for (int call = 0; call < 2; ++call) {
    try {
      if (call == 0) decode_image_file(dir / "big.jpg");
      if (call == 1) image_size(dir / "big.jpg");
      ADD_FAILURE() << "a 20000x20000 JPEG was accepted";
    } catch (const InputError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("unsupported JPEG size 20000x20000"), std::string::npos) << what;
    }
  }
}

TEST(ImageCodec, DispatchesOnMagicBytesNotExtension) {
  ScratchDir dir;
  // A PNG named .jpg and a JPEG named .png.
  std::vector<uint8_t> rgb = smooth_rgb(7, 5);
  encode_png_file(dir / "png.jpg", 7, 5, 3, rgb.data());
  write_bytes(dir / "jpeg.png", encode_jpeg(smooth_rgb(9, 11), 9, 11, JpegOptions()));
  EXPECT_EQ(image_size(dir / "png.jpg"), std::make_pair(5, 7));
  EXPECT_EQ(image_size(dir / "jpeg.png"), std::make_pair(11, 9));
  EXPECT_EQ(jpeg_size(dir / "jpeg.png"), std::make_pair(11, 9));
  const DecodedImage png = decode_image_file(dir / "png.jpg");
  EXPECT_EQ(png.image.pixels, rgb);  // lossless
  EXPECT_EQ(png.image.channels, 3);
  EXPECT_EQ(png.exif_orientation, 1);
  const DecodedImage jpg = decode_image_file(dir / "jpeg.png");
  EXPECT_EQ(jpg.image.height, 11);
  EXPECT_EQ(jpg.image.width, 9);
  EXPECT_EQ(jpg.image.channels, 3);

  // Neither: text, an empty file, two bytes of JPEG magic, a missing file, a folder.
  write_bytes(dir / "notes.jpg", "just some text, not an image\n");
  write_bytes(dir / "empty.png", "");
  write_bytes(dir / "short.jpg", "\xFF\xD8");
  for (const char* name : {"notes.jpg", "empty.png", "short.jpg"}) {
    for (int call = 0; call < 2; ++call) {
      try {
        if (call == 0) decode_image_file(dir / name);
        if (call == 1) image_size(dir / name);
        ADD_FAILURE() << name << " was accepted";
      } catch (const InputError& e) {
        EXPECT_EQ(e.file(), dir / name);
        EXPECT_NE(std::string(e.what()).find("not a PNG or JPEG image"), std::string::npos) << e.what();
      }
    }
  }
  fs::create_directories(dir / "folder.jpg");
  for (const char* name : {"missing.jpg", "folder.jpg"}) {
    try {
      decode_image_file(dir / name);
      ADD_FAILURE() << name << " was accepted";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("cannot read"), std::string::npos) << e.what();
    }
    EXPECT_THROW(image_size(dir / name), InputError);
    EXPECT_THROW(decode_jpeg_file(dir / name), InputError);
    EXPECT_THROW(jpeg_size(dir / name), InputError);
  }
}

TEST(ImageCodec, FourThreadsDecodeTheSameAsOne) {
  ScratchDir dir;
  const auto rgb = smooth_rgb(kW, kH);
  JpegOptions o420;
  o420.luma_h = o420.luma_v = 2;
  JpegOptions prog = o420;
  prog.progressive = true;
  prog.app1 = exif_payload(true, 6);
  JpegOptions grey;
  grey.in_space = JCS_GRAYSCALE;
  write_bytes(dir / "a.jpg", encode_jpeg(rgb, kW, kH, o420));
  write_bytes(dir / "b.jpg", encode_jpeg(rgb, kW, kH, prog));
  write_bytes(dir / "c.jpg", encode_jpeg(smooth_grey(kW, kH), kW, kH, grey));
  encode_png_file(dir / "d.png", kW, kH, 3, rgb.data());
  const std::string cut = encode_jpeg(rgb, kW, kH, o420);
  write_bytes(dir / "e.jpg", cut.substr(0, cut.size() / 2));
  const std::vector<std::string> files = {dir / "a.jpg", dir / "b.jpg", dir / "c.jpg", dir / "d.png", dir / "e.jpg"};

  // One thread's results: pixels and orientation, or the error message.
  using Results = std::vector<std::pair<std::vector<uint8_t>, std::string>>;
  const auto decode_all = [&files](int rounds) {
    Results r;
    for (int i = 0; i < rounds; ++i)
      for (const auto& f : files) {
        try {
          DecodedImage d = decode_image_file(f);
          r.emplace_back(std::move(d.image.pixels), std::to_string(d.exif_orientation));
        } catch (const InputError& e) {
          r.emplace_back(std::vector<uint8_t>(), e.what());
        }
      }
    return r;
  };
  const Results one = decode_all(1);
  ASSERT_EQ(one[1].second, "6");
  ASSERT_NE(one[4].second.find("truncated"), std::string::npos);
  constexpr int kThreads = 4, kRounds = 8;
  std::vector<Results> got(kThreads);
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) threads.emplace_back([&, t] { got[t] = decode_all(kRounds); });
  for (auto& th : threads) th.join();
  for (int t = 0; t < kThreads; ++t) {
    ASSERT_EQ(got[t].size(), one.size() * kRounds);
    for (size_t i = 0; i < got[t].size(); ++i) EXPECT_EQ(got[t][i], one[i % one.size()]) << "thread " << t;
  }
}
