#include "eval/report.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <iomanip>
#include <sstream>

#include "eval/colormap.h"
#include "eval/evaluate.h"
#include "run/run_log.h"
#include "util/progress.h"
#include "util/fs.h"

namespace fs = std::filesystem;

namespace ablenerf {
namespace {

// At most this many views appear side by side in the report.
constexpr int kMaxViews = 4;
// Display width of each embedded view, CSS pixels (small renders are upscaled, pixelated).
constexpr int kViewWidthPx = 220;
// Chart plot-area margins (left, right, top, bottom), SVG units.
constexpr int kMarginL = 64, kMarginR = 16, kMarginT = 28, kMarginB = 44;
// Target number of ticks on a linear axis.
constexpr int kLinearTicks = 5;
// Cells of the colour-bar legend.
constexpr int kColourBarCells = 32;

std::string fmt(double v, int precision = 4) {
  if (!std::isfinite(v)) return "n/a";
  std::ostringstream s;
  s << std::setprecision(precision) << v;
  return s.str();
}

std::string fmt_json(const nlohmann::json& v, int precision = 4) {
  if (v.is_number()) return fmt(v.get<double>(), precision);
  if (v.is_string()) return html_escape(v.get<std::string>());
  return "n/a";
}

// "Nice" tick spacing: 1, 2 or 5 times a power of ten, about range / kLinearTicks.
double nice_step(double range) {
  const double raw = range / kLinearTicks;
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  const double r = raw / mag;
  return mag * (r < 1.5 ? 1 : r < 3.5 ? 2 : r < 7.5 ? 5 : 10);
}

std::string colour_bar(double lo, double hi, const std::string& caption) {
  const auto values = torch::linspace(0.0, 1.0, kColourBarCells).unsqueeze(0);
  const auto rgb = colormap(values, 0.0, 1.0)[0];
  const int cell = 8, bar_h = 14, width = cell * kColourBarCells;
  std::ostringstream s;
  s << "<div class=\"legend\">" << html_escape(caption) << " <svg width=\"" << width + 80 << "\" height=\"" << bar_h + 4
    << "\" xmlns=\"http://www.w3.org/2000/svg\">";
  s << "<text x=\"0\" y=\"" << bar_h - 2 << "\" font-size=\"11\">" << fmt(lo) << "</text>";
  for (int i = 0; i < kColourBarCells; ++i) {
    auto c = rgb[i];
    s << "<rect x=\"" << 36 + i * cell << "\" y=\"1\" width=\"" << cell << "\" height=\"" << bar_h << "\" fill=\"rgb("
      << std::lround(c[0].item<float>() * 255) << "," << std::lround(c[1].item<float>() * 255) << ","
      << std::lround(c[2].item<float>() * 255) << ")\"/>";
  }
  s << "<text x=\"" << 40 + width << "\" y=\"" << bar_h - 2 << "\" font-size=\"11\">" << fmt(hi)
    << "</text></svg></div>";
  return s.str();
}

std::string img_tag(const std::string& path, const std::string& alt) {
  if (!fs::exists(path)) return "<div class=\"missing\">" + html_escape(alt) + " missing</div>";
  return "<img alt=\"" + html_escape(alt) + "\" width=\"" + std::to_string(kViewWidthPx) +
         "\" src=\"data:image/png;base64," + base64_encode(read_file(path)) + "\">";
}

struct SplitMetrics {
  std::string split, dir;
  nlohmann::json m;
};

// Every RUN/eval/SPLIT/metrics.json that parses, "test" first.
std::vector<SplitMetrics> load_metrics(const RunFolder& run) {
  std::vector<SplitMetrics> out;
  const fs::path root = run.path("eval");
  if (!fs::is_directory(root)) return out;
  for (const auto& e : fs::directory_iterator(root)) {
    const auto file = e.path() / "metrics.json";
    if (!e.is_directory() || !fs::exists(file)) continue;
    try {
      out.push_back({e.path().filename().string(), e.path().string(), nlohmann::json::parse(read_file(file.string()))});
    } catch (const nlohmann::json::exception&) {
      // A damaged metrics file is left out of the report rather than failing it.
    }
  }
  std::sort(out.begin(), out.end(), [](const SplitMetrics& a, const SplitMetrics& b) {
    return std::make_pair(a.split != "test", a.split) < std::make_pair(b.split != "test", b.split);
  });
  return out;
}

// A key's value as config.toml writes it: the report reads the [train] section by name, since the
// train module sits above this one (docs/ARCHITECTURE.md, "Modules").
std::string config_value(const Config& c, const std::string& key) {
  for (const auto& [k, v] : c.items())
    if (k == key) return v;
  return "?";
}

std::string summary_section(const RunFolder& run, const RunLog& log) {
  std::ostringstream s;
  s << "<h2>Run</h2><table class=\"kv\">";
  auto row = [&](const std::string& k, const std::string& v) {
    s << "<tr><th>" << html_escape(k) << "</th><td>" << v << "</td></tr>";
  };
  row("Run folder", html_escape(fs::absolute(run.dir).lexically_normal().string()));
  row("Dataset", run.data_dir.empty() ? "n/a" : html_escape(run.data_dir));
  row("Steps", log.last_step >= 0 ? std::to_string(log.last_step) + " of " + config_value(run.config, "train.steps")
                                  : "no training log");
  row("Training time", log.elapsed_s >= 0 ? Progress::format_duration(log.elapsed_s) : "n/a");
  if (!log.train.empty()) {
    const auto& last = log.train.back();
    row("Last train loss", fmt_json(last.value("loss", nlohmann::json())));
    row("Last train PSNR (dB)", fmt_json(last.value("psnr", nlohmann::json())));
  }
  row("Parameters", std::to_string(AbleNerf(run.config.get<ModelConfig>())->parameter_count()));
  if (log.skipped_lines) row("Unreadable log lines", std::to_string(log.skipped_lines));
  s << "</table>";
  return s.str();
}

// What `export --points / --mesh` wrote (RUN/exports.json, geometry/export_geometry.h), newest
// last: the files, their sizes and times. Nothing when the run has no exports; a file that cannot
// be read is said in one line instead of failing the report.
std::string exports_section(const RunFolder& run) {
  nlohmann::json all;
  try {
    all = run.exports();
  } catch (const std::exception& e) {
    return "<h2>Exports</h2><p class=\"note\">" + html_escape(e.what()) + "</p>";
  }
  if (all.empty()) return "";
  std::ostringstream s;
  s << "<h2>Exports</h2><table><tr><th>when</th><th>file</th><th>what</th><th>frame</th><th>seconds</th></tr>";
  const auto cell = [](const nlohmann::json& e, const char* key) {
    return e.is_object() && e.contains(key) ? fmt_json(e[key]) : std::string("");
  };
  for (const auto& e : all) {
    if (!e.is_object()) continue;
    const std::string when = e.value("when", ""), frame = e.value("frame", "");
    if (e.contains("points") && e["points"].is_object()) {
      const auto& p = e["points"];
      s << "<tr><td>" << html_escape(when) << "</td><td>" << html_escape(p.value("path", "")) << "</td><td>"
        << cell(p, "count") << " points (of " << cell(p, "raw") << " from " << cell(e, "views") << " views at "
        << html_escape(e.value("image", "")) << ")</td><td>" << html_escape(frame) << "</td><td>" << cell(p, "seconds")
        << "</td></tr>";
    }
    if (e.contains("mesh") && e["mesh"].is_object()) {
      const auto& m = e["mesh"];
      s << "<tr><td>" << html_escape(when) << "</td><td>" << html_escape(m.value("path", "")) << "</td><td>"
        << html_escape(m.value("method", "")) << " mesh, " << cell(m, "vertices") << " vertices, "
        << cell(m, "triangles") << " triangles</td><td>" << html_escape(frame) << "</td><td>" << cell(m, "seconds")
        << "</td></tr>";
    }
  }
  s << "</table>";
  // The newest export's picture of its points and cameras (geometry/preview.h), when it is there.
  for (auto it = all.rbegin(); it != all.rend(); ++it) {
    if (!it->is_object() || !it->contains("preview") || !(*it)["preview"].is_string()) continue;
    const std::string png = (*it)["preview"].get<std::string>();
    if (fs::exists(png)) s << "<p>" << img_tag(png, "the exported points with the cameras that saw them") << "</p>";
    break;
  }
  return s.str();
}

// The depth errors of a metrics object: the attention front's and the mean's (docs/MODEL.md, section
// 9); metrics from before the front show the mean's alone.
std::string depth_cell(const nlohmann::json& m) {
  const auto mean = fmt_json(m.value("depth_mae", nlohmann::json()));
  if (!m.contains("depth_mae_front")) return mean;
  return fmt_json(m["depth_mae_front"]) + " / " + mean;
}

std::string metrics_section(const std::vector<SplitMetrics>& all) {
  std::ostringstream s;
  s << "<h2>Metrics</h2>";
  if (all.empty()) {
    s << "<p>No evaluation yet (run <code>ablenerf eval --run RUN</code>).</p>";
    return s.str();
  }
  s << "<table><tr><th>split</th><th>views</th><th>PSNR (dB)</th><th>SSIM</th><th>LPIPS (Alex)</th>"
       "<th>depth MAE (front / mean)</th><th>s / image</th><th>step</th><th>SSIM variant</th><th>protocol</th></tr>";
  for (const auto& sm : all) {
    const auto& m = sm.m;
    const auto mean = m.value("mean", nlohmann::json::object());
    s << "<tr><td>" << html_escape(sm.split) << "</td><td>" << m.value("images", nlohmann::json::array()).size()
      << "</td><td>" << fmt_json(mean.value("psnr", nlohmann::json())) << "</td><td>"
      << fmt_json(mean.value("ssim", nlohmann::json())) << "</td><td>"
      << fmt_json(mean.value("lpips", nlohmann::json())) << "</td><td>" << depth_cell(mean) << "</td><td>"
      << fmt_json(m.value("seconds_per_image", nlohmann::json()), 3) << "</td><td>"
      << fmt_json(m.value("step", nlohmann::json())) << "</td><td>"
      << fmt_json(m.value("ssim_variant", nlohmann::json()))
      << "</td><td>"
      // How the held-out views were scored (evaluate.h): plain, aligned cameras, fitted look (right halves).
      << html_escape(m.value("protocol", std::string("plain"))) << "</td></tr>";
  }
  s << "</table>";
  for (const auto& sm : all) {
    s << "<details><summary>Per image: " << html_escape(sm.split) << "</summary><table><tr><th>#</th><th>file</th>"
      << "<th>PSNR</th><th>SSIM</th><th>LPIPS</th><th>depth MAE (front / mean)</th><th>seconds</th></tr>";
    for (const auto& im : sm.m.value("images", nlohmann::json::array())) {
      s << "<tr><td>" << fmt_json(im.value("index", nlohmann::json())) << "</td><td>"
        << html_escape(fs::path(im.value("file", std::string())).filename().string()) << "</td><td>"
        << fmt_json(im.value("psnr", nlohmann::json())) << "</td><td>" << fmt_json(im.value("ssim", nlohmann::json()))
        << "</td><td>" << fmt_json(im.value("lpips", nlohmann::json())) << "</td><td>" << depth_cell(im) << "</td><td>"
        << fmt_json(im.value("seconds", nlohmann::json()), 3) << "</td></tr>";
    }
    s << "</table></details>";
  }
  const auto lp = all.front().m.value("lpips_weights", nlohmann::json());
  s << "<p class=\"note\">PSNR and SSIM on 8-bit-equivalent float renders in [0,1]; SSIM variant as listed; "
    << "LPIPS " << (lp.is_string() ? "from " + html_escape(lp.get<std::string>()) : std::string("not computed"))
    << ". Depth MAE (scene units) over pixels with ground-truth depth &gt; 0 and alpha &gt; "
    << fmt(kDepthAlphaThreshold) << ", using the attention mean depth.</p>";
  return s.str();
}

std::string views_section(const std::vector<SplitMetrics>& all) {
  std::ostringstream s;
  s << "<h2>Views</h2>";
  if (all.empty()) {
    s << "<p>No rendered views yet.</p>";
    return s.str();
  }
  const auto& sm = all.front();
  const auto images = sm.m.value("images", nlohmann::json::array());
  const double near = sm.m.value("near", 2.0), far = sm.m.value("far", 6.0);
  s << "<p>Split <b>" << html_escape(sm.split) << "</b>: ground truth | render | error | depth.</p>";
  s << colour_bar(0.0, sm.m.value("error_map_max", kErrorMapMax), "error: mean |render - gt| over RGB")
    << colour_bar(near, far, "depth: attention-weighted mean depth (near to far)");
  const int n = std::min<int>(kMaxViews, static_cast<int>(images.size()));
  for (int i = 0; i < n; ++i) {
    const auto& im = images[static_cast<size_t>(i)];
    const std::string stem = sm.dir + "/r_" + std::to_string(im.value("index", i));
    s << "<div class=\"views\"><figure>" << img_tag(stem + "_gt.png", "ground truth")
      << "<figcaption>ground truth</figcaption></figure><figure>" << img_tag(stem + ".png", "render")
      << "<figcaption>render, PSNR " << fmt_json(im.value("psnr", nlohmann::json()))
      << " dB</figcaption></figure><figure>" << img_tag(stem + "_error.png", "error")
      << "<figcaption>error</figcaption></figure><figure>" << img_tag(stem + "_depth.png", "depth")
      << "<figcaption>depth</figcaption></figure></div>";
  }
  return s.str();
}

std::string curves_section(const RunLog& log) {
  std::ostringstream s;
  s << "<h2>Training</h2>";
  ChartSeries loss{"train loss", "#c0392b", {}, {}, false};
  ChartSeries train_psnr{"train PSNR", "#2c7fb8", {}, {}, false};
  ChartSeries held_out{"held-out PSNR", "#e67e22", {}, {}, true};
  // The same PSNR curves against wall-clock minutes of training: what a time budget buys.
  ChartSeries train_psnr_t{"train PSNR", "#2c7fb8", {}, {}, false};
  ChartSeries held_out_t{"held-out PSNR", "#e67e22", {}, {}, true};
  auto add = [](ChartSeries& c, const nlohmann::json& r, const char* x_key, double x_scale, const char* key) {
    if (r.contains(x_key) && r[x_key].is_number() && r.contains(key) && r[key].is_number()) {
      c.x.push_back(r[x_key].get<double>() * x_scale);
      c.y.push_back(r[key].get<double>());
    }
  };
  constexpr double kMinutesPerSecond = 1.0 / 60.0;
  // The loss's terms (train/grad_accumulation.h) beside their sum, each in the order it first
  // appears in the log.
  static constexpr std::array<const char*, 8> kTermColours = {"#7f7f7f", "#9467bd", "#2ca02c", "#17becf",
                                                              "#bcbd22", "#8c564b", "#e377c2", "#1f77b4"};
  std::vector<ChartSeries> terms;
  for (const auto& r : log.train) {
    if (!r.contains("step") || !r["step"].is_number() || !r.contains("terms") || !r["terms"].is_object()) continue;
    for (const auto& [name, value] : r["terms"].items()) {
      if (!value.is_number()) continue;
      auto it = std::find_if(terms.begin(), terms.end(), [&](const ChartSeries& c) { return c.label == name; });
      if (it == terms.end()) {
        terms.push_back({name, kTermColours[terms.size() % kTermColours.size()], {}, {}, false});
        it = terms.end() - 1;
      }
      it->x.push_back(r["step"].get<double>());
      it->y.push_back(value.get<double>());
    }
  }
  for (const auto& r : log.train) {
    add(loss, r, "step", 1.0, "loss");
    add(train_psnr, r, "step", 1.0, "psnr");
    add(train_psnr_t, r, "elapsed_s", kMinutesPerSecond, "psnr");
  }
  for (const auto& r : log.eval) {
    add(held_out, r, "step", 1.0, "psnr");
    add(held_out_t, r, "elapsed_s", kMinutesPerSecond, "psnr");
  }
  if (loss.x.empty() && held_out.x.empty()) {
    s << "<p>No training log (log.jsonl) in this run.</p>";
    return s.str();
  }
  std::vector<ChartSeries> losses{loss};
  losses.insert(losses.end(), terms.begin(), terms.end());
  s << "<div class=\"charts\">" << svg_chart("Loss and its terms (log scale)", "step", "loss", losses, true)
    << svg_chart("PSNR", "step", "dB", {train_psnr, held_out}, false)
    << svg_chart("PSNR against training time", "minutes", "dB", {train_psnr_t, held_out_t}, false) << "</div>";
  return s.str();
}

std::string config_section(const RunFolder& run) {
  std::ostringstream s;
  s << "<h2>Config</h2><details open><summary>" << run.config.items().size()
    << " keys (config.toml)</summary><table class=\"kv\">";
  for (const auto& [k, v] : run.config.items())
    s << "<tr><th>" << html_escape(k) << "</th><td>" << html_escape(v) << "</td></tr>";
  s << "</table></details>";
  return s.str();
}

constexpr const char* kStyle = R"(
body { font-family: sans-serif; margin: 24px; color: #222; max-width: 1100px; }
h1 { font-size: 22px; } h2 { font-size: 18px; margin-top: 28px; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; margin: 8px 0; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: left; }
table.kv th { background: #f4f4f4; font-weight: normal; }
.views { display: flex; gap: 8px; margin: 8px 0; }
figure { margin: 0; } figcaption { font-size: 12px; text-align: center; }
img { image-rendering: pixelated; border: 1px solid #ccc; }
.charts { display: flex; flex-wrap: wrap; gap: 16px; }
.legend { font-size: 12px; margin: 4px 0; } .legend svg { vertical-align: middle; } .note { font-size: 12px; color: #555; }
.missing { width: 220px; height: 60px; border: 1px dashed #aaa; font-size: 12px; }
)";

}  // namespace

std::string base64_encode(const std::string& bytes) {
  static constexpr char kAlphabet[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  // Each 3-byte group becomes four 6-bit digits.
  for (; i + 3 <= bytes.size(); i += 3) {
    const uint32_t v =
        (uint32_t(uint8_t(bytes[i])) << 16) | (uint32_t(uint8_t(bytes[i + 1])) << 8) | uint8_t(bytes[i + 2]);
    for (int shift = 18; shift >= 0; shift -= 6) out += kAlphabet[(v >> shift) & 0x3F];
  }
  // A trailing 1 or 2 bytes: zero-fill, emit 2 or 3 digits, pad with '='.
  const size_t rest = bytes.size() - i;
  if (rest) {
    uint32_t v = uint32_t(uint8_t(bytes[i])) << 16;
    if (rest == 2) v |= uint32_t(uint8_t(bytes[i + 1])) << 8;
    out += kAlphabet[(v >> 18) & 0x3F];
    out += kAlphabet[(v >> 12) & 0x3F];
    out += rest == 2 ? kAlphabet[(v >> 6) & 0x3F] : '=';
    out += '=';
  }
  return out;
}

std::string html_escape(const std::string& s) {
  std::string o;
  o.reserve(s.size());
  for (char c : s) {
    switch (c) {
      case '&': o += "&amp;"; break;
      case '<': o += "&lt;"; break;
      case '>': o += "&gt;"; break;
      case '"': o += "&quot;"; break;
      default: o += c;
    }
  }
  return o;
}

std::string svg_chart(const std::string& title, const std::string& x_label, const std::string& y_label,
                      const std::vector<ChartSeries>& series, bool log_y, int width, int height) {
  // Data ranges over every plottable point (log axis: positive values only, in log10).
  double x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
  auto ty = [&](double y) { return log_y ? std::log10(y) : y; };
  auto usable = [&](double x, double y) { return std::isfinite(x) && std::isfinite(y) && (!log_y || y > 0); };
  for (const auto& s : series)
    for (size_t i = 0; i < s.x.size(); ++i)
      if (usable(s.x[i], s.y[i])) {
        x0 = std::min(x0, s.x[i]), x1 = std::max(x1, s.x[i]);
        y0 = std::min(y0, ty(s.y[i])), y1 = std::max(y1, ty(s.y[i]));
      }
  std::ostringstream o;
  o << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" << width << "\" height=\"" << height
    << "\" font-family=\"sans-serif\" font-size=\"11\"><rect width=\"100%\" height=\"100%\" fill=\"#fff\"/>"
    << "<text x=\"" << width / 2 << "\" y=\"16\" text-anchor=\"middle\" font-size=\"13\">" << html_escape(title)
    << "</text>";
  if (!(x0 <= x1)) {
    o << "<text x=\"" << width / 2 << "\" y=\"" << height / 2 << "\" text-anchor=\"middle\">no data</text></svg>";
    return o.str();
  }
  // Degenerate ranges (one point, constant values) get a symmetric pad.
  if (x1 - x0 <= 0) x0 -= 1, x1 += 1;
  if (y1 - y0 <= 0) {
    const double pad = log_y ? 0.5 : std::max(1e-3, std::abs(y0) * 0.1);
    y0 -= pad, y1 += pad;
  }
  if (log_y) y0 = std::floor(y0 * 2) / 2, y1 = std::ceil(y1 * 2) / 2;  // half-decade bounds
  const double pw = width - kMarginL - kMarginR, ph = height - kMarginT - kMarginB;
  auto px = [&](double x) { return kMarginL + (x - x0) / (x1 - x0) * pw; };
  auto py = [&](double v) { return kMarginT + (1.0 - (v - y0) / (y1 - y0)) * ph; };
  o << std::fixed << std::setprecision(1);
  // Y ticks: decades on a log axis, nice steps on a linear one.
  std::vector<std::pair<double, std::string>> yticks;
  if (log_y) {
    for (double e = std::ceil(y0); e <= y1 + 1e-9; e += 1) yticks.push_back({e, fmt(std::pow(10.0, e), 3)});
    if (yticks.size() < 2)
      for (double v : {y0, y1}) yticks.push_back({v, fmt(std::pow(10.0, v), 3)});
  } else {
    const double st = nice_step(y1 - y0);
    for (double v = std::ceil(y0 / st) * st; v <= y1 + st * 1e-6; v += st) yticks.push_back({v, fmt(v, 4)});
  }
  for (const auto& [v, label] : yticks) {
    o << "<line x1=\"" << kMarginL << "\" x2=\"" << kMarginL + pw << "\" y1=\"" << py(v) << "\" y2=\"" << py(v)
      << "\" stroke=\"#e4e4e4\"/><text x=\"" << kMarginL - 4 << "\" y=\"" << py(v) + 4 << "\" text-anchor=\"end\">"
      << label << "</text>";
  }
  const double xs = nice_step(x1 - x0);
  for (double v = std::ceil(x0 / xs) * xs; v <= x1 + xs * 1e-6; v += xs)
    o << "<line x1=\"" << px(v) << "\" x2=\"" << px(v) << "\" y1=\"" << kMarginT << "\" y2=\"" << kMarginT + ph
      << "\" stroke=\"#f0f0f0\"/><text x=\"" << px(v) << "\" y=\"" << kMarginT + ph + 14 << "\" text-anchor=\"middle\">"
      << fmt(v, 6) << "</text>";
  o << "<rect x=\"" << kMarginL << "\" y=\"" << kMarginT << "\" width=\"" << pw << "\" height=\"" << ph
    << "\" fill=\"none\" stroke=\"#888\"/>";
  o << "<text x=\"" << kMarginL + pw / 2 << "\" y=\"" << height - 6 << "\" text-anchor=\"middle\">"
    << html_escape(x_label) << "</text><text transform=\"translate(12," << kMarginT + ph / 2
    << ") rotate(-90)\" text-anchor=\"middle\">" << html_escape(y_label) << "</text>";
  // Legend box behind the labels so that lines running through the corner stay readable.
  int plotted = 0;
  for (const auto& s : series)
    for (size_t i = 0; i < s.x.size(); ++i)
      if (usable(s.x[i], s.y[i])) {
        ++plotted;
        break;
      }
  int legend_row = 0;
  std::ostringstream legend;
  legend << std::fixed << std::setprecision(1);
  for (const auto& s : series) {
    std::ostringstream pts;
    pts << std::fixed << std::setprecision(1);
    size_t n = 0;
    for (size_t i = 0; i < s.x.size(); ++i) {
      if (!usable(s.x[i], s.y[i])) continue;
      ++n;
      if (s.points)
        o << "<circle cx=\"" << px(s.x[i]) << "\" cy=\"" << py(ty(s.y[i])) << "\" r=\"3.5\" fill=\"" << s.colour
          << "\"/>";
      else
        pts << px(s.x[i]) << "," << py(ty(s.y[i])) << " ";
    }
    if (!s.points && n)
      o << "<polyline fill=\"none\" stroke=\"" << s.colour << "\" stroke-width=\"1.5\" points=\"" << pts.str()
        << "\"/>";
    if (!n) continue;
    const double ly = kMarginT + 12 + 14 * legend_row++;
    legend << "<rect x=\"" << kMarginL + pw - 120 << "\" y=\"" << ly - 8 << "\" width=\"10\" height=\"10\" fill=\""
           << s.colour << "\"/><text x=\"" << kMarginL + pw - 105 << "\" y=\"" << ly + 1 << "\">"
           << html_escape(s.label) << "</text>";
  }
  o << "<rect x=\"" << kMarginL + pw - 126 << "\" y=\"" << kMarginT + 2 << "\" width=\"122\" height=\""
    << 14 * plotted + 4 << "\" fill=\"#fff\" fill-opacity=\"0.85\" stroke=\"#ccc\"/>" << legend.str() << "</svg>";
  return o.str();
}

void write_report(const RunFolder& run) {
  const RunLog log = read_run_log(run.log_path());
  const auto metrics = load_metrics(run);
  std::ostringstream h;
  const std::time_t now = std::time(nullptr);
  char when[64];
  std::strftime(when, sizeof when, "%Y-%m-%d %H:%M:%S", std::localtime(&now));
  h << "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>ablenerf report: "
    << html_escape(fs::path(run.dir).filename().string()) << "</title><style>" << kStyle << "</style></head><body>"
    << "<h1>ABLE-NeRF run " << html_escape(fs::path(run.dir).filename().string()) << "</h1>"
    << "<p class=\"note\">Written " << when << " by ablenerf " << ABLENERF_VERSION << ".</p>"
    << summary_section(run, log) << metrics_section(metrics) << views_section(metrics) << curves_section(log)
    << exports_section(run) << config_section(run) << "</body></html>\n";
  write_file_atomic(run.report_path(), h.str());
}

}  // namespace ablenerf
