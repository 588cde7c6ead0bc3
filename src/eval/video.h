#pragma once
// H.264 video through an external ffmpeg process: raw RGB24 frames are piped to
//   ffmpeg -y -f rawvideo -pix_fmt rgb24 -s WxH -r FPS -i - -c:v libx264 -pix_fmt yuv420p FILE
// (no video library is linked; ffmpeg must be on PATH).
#include <torch/torch.h>

#include <cstdio>
#include <string>

namespace ablenerf {

// True when `ffmpeg` is found on PATH.
bool ffmpeg_available();

// Quotes a string for /bin/sh (single quotes, embedded ones escaped).
std::string shell_quote(const std::string& s);

class VideoWriter {
 public:
  // Starts ffmpeg writing `path`. libx264 with yuv420p needs even sides: throws InputError
  // ("--out", ...) for odd ones, and when ffmpeg cannot be started.
  VideoWriter(const std::string& path, int width, int height, double fps);
  ~VideoWriter();  // closes the pipe if close() was not called (errors ignored)
  VideoWriter(const VideoWriter&) = delete;
  VideoWriter& operator=(const VideoWriter&) = delete;

  // Appends one frame: uint8 (H,W,3) or float (H,W,3) in [0,1] (rounded like write_png).
  void write(const torch::Tensor& frame);
  // Waits for ffmpeg; throws std::runtime_error when it failed (its stderr went to ours).
  void close();

 private:
  std::string path_;
  int width_, height_;
  FILE* pipe_ = nullptr;
};

}  // namespace ablenerf
