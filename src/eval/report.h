#pragma once
// RUN/report.html: one self-contained page (images as base64 data URIs, charts as inline SVG,
// no scripts, nothing fetched) summarising a run: config, dataset, training time, the eval
// metrics (mean and per image), loss / PSNR curves from log.jsonl and a few views side by side
// (ground truth | render | error | depth) from RUN/eval/SPLIT.
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "eval/run_folder.h"

namespace ablenerf {

// log.jsonl split by record type. Lines that are not JSON objects (e.g. a line cut short by a
// crash) are skipped and counted.
struct RunLog {
  std::vector<nlohmann::json> train, eval;
  int64_t last_step = -1;     // largest "step" of any record, -1 when none
  double elapsed_s = -1;      // "elapsed_s" of the last train record, -1 when none
  int64_t skipped_lines = 0;
};
// A missing file gives an empty log.
RunLog read_run_log(const std::string& path);

// Standard base64 (RFC 4648, with '=' padding).
std::string base64_encode(const std::string& bytes);

// One line (or point set) of a chart.
struct ChartSeries {
  std::string label;
  std::string colour;      // CSS colour
  std::vector<double> x, y;
  bool points = false;     // markers only, no line
};
// An inline <svg> line chart. With log_y, values <= 0 are left out and the axis has decade ticks.
std::string svg_chart(const std::string& title, const std::string& x_label, const std::string& y_label,
                      const std::vector<ChartSeries>& series, bool log_y, int width = 560, int height = 300);

// HTML-escapes text (&, <, >, ").
std::string html_escape(const std::string& s);

// Writes RUN/report.html atomically (overwriting an earlier one).
void write_report(const RunFolder& run);

}  // namespace ablenerf
