#pragma once
// RUN/log.jsonl: the training log, one JSON object per line ({"type":"train", ...} or
// {"type":"eval", ...}; fields in run/run_folder.h). Written by the trainer, read by the report.
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

namespace ablenerf {

// Appends `record` as one line. The file is opened for each record, so a crash loses at most the
// line being written. Throws EnvironmentError naming the file (disk full, no permission).
void append_run_log(const std::string& path, const nlohmann::json& record);

// log.jsonl split by record type. Lines that are not JSON objects (e.g. a line cut short by a
// crash) are skipped and counted.
struct RunLog {
  std::vector<nlohmann::json> train, eval;
  int64_t last_step = -1;  // largest "step" of any record, -1 when none
  double elapsed_s = -1;   // "elapsed_s" of the last train record, -1 when none
  int64_t skipped_lines = 0;
};

// A missing file gives an empty log; one that exists but cannot be read is an InputError naming it.
RunLog read_run_log(const std::string& path);

}  // namespace ablenerf
