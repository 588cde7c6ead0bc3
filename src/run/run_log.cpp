#include "run/run_log.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <filesystem>
#include <sstream>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

void append_run_log(const std::string& path, const nlohmann::json& record) {
  const std::string line = record.dump() + "\n";
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0666);
  if (fd < 0) throw write_error(path, errno);
  int err = 0;
  size_t done = 0;
  while (done < line.size()) {
    const ssize_t n = ::write(fd, line.data() + done, line.size() - done);
    if (n < 0) {
      if (errno == EINTR) continue;
      err = errno;
      break;
    }
    done += static_cast<size_t>(n);
  }
  if (::close(fd) != 0 && err == 0) err = errno;
  if (err != 0) throw write_error(path, err);
}

RunLog read_run_log(const std::string& path) {
  RunLog log;
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return log;
  std::istringstream in(read_file(path));
  std::string line;
  while (std::getline(in, line)) {
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    nlohmann::json j;
    try {
      j = nlohmann::json::parse(line);
    } catch (const nlohmann::json::exception&) {
      ++log.skipped_lines;
      continue;
    }
    if (!j.is_object()) {
      ++log.skipped_lines;
      continue;
    }
    if (j.contains("step") && j["step"].is_number_integer())
      log.last_step = std::max(log.last_step, j["step"].get<int64_t>());
    const std::string type = j.value("type", std::string());
    if (type == "train") {
      log.train.push_back(j);
      if (j.contains("elapsed_s") && j["elapsed_s"].is_number()) log.elapsed_s = j["elapsed_s"].get<double>();
    } else if (type == "eval") {
      log.eval.push_back(j);
    }
  }
  return log;
}

}  // namespace ablenerf
