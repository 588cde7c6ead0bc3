#pragma once
// RUN/report.html: one self-contained page (images as base64 data URIs, charts as inline SVG,
// no scripts, nothing fetched) summarising a run: config, dataset, training time, the eval
// metrics (mean and per image), loss / PSNR curves from log.jsonl and a few views side by side
// (ground truth | render | error | depth) from RUN/eval/SPLIT.
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "run/run_folder.h"

namespace ablenerf {

// Standard base64 (RFC 4648, with '=' padding).
std::string base64_encode(const std::string& bytes);

// One line (or point set) of a chart.
struct ChartSeries {
  std::string label;
  std::string colour;  // CSS colour
  std::vector<double> x, y;
  bool points = false;  // markers only, no line
};
// An inline <svg> line chart. With log_y, values <= 0 are left out and the axis has decade ticks.
std::string svg_chart(const std::string& title, const std::string& x_label, const std::string& y_label,
                      const std::vector<ChartSeries>& series, bool log_y, int width = 560, int height = 300);

// HTML-escapes text (&, <, >, ").
std::string html_escape(const std::string& s);

// Writes RUN/report.html atomically (overwriting an earlier one).
void write_report(const RunFolder& run);

}  // namespace ablenerf
