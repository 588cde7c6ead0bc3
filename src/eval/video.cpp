#include "eval/video.h"

#include <sys/wait.h>

#include <csignal>
#include <sstream>
#include <stdexcept>

#include "util/errors.h"
#include "util/image_io.h"
#include "util/subprocess.h"

namespace ablenerf {

bool ffmpeg_available() { return program_available("ffmpeg"); }

std::string shell_quote(const std::string& s) {
  std::string q = "'";
  for (char c : s) {
    if (c == '\'')
      q += "'\\''";  // close, escaped quote, reopen
    else
      q += c;
  }
  return q + "'";
}

VideoWriter::VideoWriter(const std::string& path, int width, int height, double fps)
    : path_(path), width_(width), height_(height) {
  if (width <= 0 || height <= 0 || width % 2 || height % 2)
    throw InputError("--out", "",
                     "H.264 (yuv420p) needs even frame sides, got " + std::to_string(width) + "x" +
                         std::to_string(height) + " (use --width/--height)");
  if (!(fps > 0)) throw InputError("--fps", "", "must be positive");
  // A dying ffmpeg must surface as a write error here, not kill us with SIGPIPE.
  std::signal(SIGPIPE, SIG_IGN);
  std::ostringstream cmd;
  cmd << "ffmpeg -hide_banner -loglevel error -y -f rawvideo -pix_fmt rgb24 -s " << width << "x" << height << " -r "
      << fps << " -i - -c:v libx264 -pix_fmt yuv420p " << shell_quote(path);
  pipe_ = ::popen(cmd.str().c_str(), "w");
  if (!pipe_) throw InputError(path, "", "cannot start ffmpeg");
}

VideoWriter::~VideoWriter() {
  if (pipe_) ::pclose(pipe_);
}

void VideoWriter::write(const torch::Tensor& frame) {
  TORCH_CHECK(pipe_, "VideoWriter: already closed");
  TORCH_CHECK(frame.dim() == 3 && frame.size(0) == height_ && frame.size(1) == width_ && frame.size(2) == 3,
              "VideoWriter: expected a (", height_, ",", width_, ",3) frame, got ", frame.sizes());
  const auto bytes = (frame.scalar_type() == torch::kUInt8 ? frame : to_uint8(frame)).to(torch::kCPU).contiguous();
  const size_t n = static_cast<size_t>(bytes.numel());
  if (std::fwrite(bytes.data_ptr<uint8_t>(), 1, n, pipe_) != n)
    throw std::runtime_error("ffmpeg stopped accepting frames for " + path_);
}

void VideoWriter::close() {
  if (!pipe_) return;
  const int status = ::pclose(pipe_);
  pipe_ = nullptr;
  if (status == -1 || !WIFEXITED(status) || WEXITSTATUS(status) != 0)
    throw std::runtime_error("ffmpeg failed writing " + path_);
}

}  // namespace ablenerf
