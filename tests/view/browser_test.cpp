// The viewer page in a real headless browser (Debian's Chromium; skipped when `chromium` is not on
// PATH): it loads, reads the cameras, an image arrives and is drawn, a drag through the page's mouse
// handlers moves the camera, and a screenshot of the page is kept in the test's artifacts
// (BUILD/artifacts/viewer.png) showing the scene.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <regex>
#include <thread>

#include "eval/eval_fixtures.h"
#include "test_util.h"
#include "util/fs.h"
#include "util/image_io.h"
#include "util/subprocess.h"
#include "view/view_server.h"

using namespace ablenerf;
namespace fs = std::filesystem;

namespace {

bool have_chromium() { return program_available("chromium"); }

// Chromium, headless, on `url`; its stdout into `out`. Virtual time lets the page's timers run
// without waiting; network fetches (the renders) still complete.
// A fresh profile per call (next to `out`): nothing carried over between runs or tests.
int chromium(const std::string& args, const std::string& url, const std::string& out) {
  const std::string cmd =
      "timeout 120 chromium --headless=new --no-sandbox --disable-gpu --no-first-run "
      "--disable-dev-shm-usage --user-data-dir='" +
      out +
      ".profile' --window-size=420,360 "
      "--virtual-time-budget=15000 " +
      args + " '" + url + "' > '" + out + "' 2> '" + out + ".log'";
  return std::system(cmd.c_str());
}

struct PageState {
  std::string pose;
  int images = 0;
  std::string drawn;             // the sizes drawn, in order
  int shown_w = 0, shown_h = 0;  // the size the view is shown at (data-display)
  int points_drawn = -1;         // exported points drawn over the view (data-points-drawn)
};

PageState page_state(const std::string& dom) {
  PageState s;
  std::smatch m;
  if (std::regex_search(dom, m, std::regex("<pre id=\"pose\"[^>]*>([^<]*)</pre>"))) s.pose = m[1];
  if (std::regex_search(dom, m, std::regex("data-images=\"([0-9]+)\""))) s.images = std::stoi(m[1]);
  if (std::regex_search(dom, m, std::regex("data-drawn=\"([0-9x ]*)\""))) s.drawn = m[1];
  if (std::regex_search(dom, m, std::regex("data-points-drawn=\"([0-9]+)\""))) s.points_drawn = std::stoi(m[1]);
  if (std::regex_search(dom, m, std::regex("data-display=\"([0-9]+)x([0-9]+)\""))) {
    s.shown_w = std::stoi(m[1]);
    s.shown_h = std::stoi(m[2]);
  }
  return s;
}

}  // namespace

TEST(ViewerPage, LoadsDrawsAndADragMovesTheCamera) {
  if (!have_chromium()) GTEST_SKIP() << "chromium not on PATH (Debian: apt-get install chromium)";
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 2, 32, 32, false);
  test::make_tiny_run(t / "run", t / "scene");
  ViewSession session(t / "run", torch::kCPU);
  ViewServer server(session, "127.0.0.1", 0);
  const int port = server.bind();
  auto serving = std::make_unique<ServingThread>(server);
  const std::string url = "http://127.0.0.1:" + std::to_string(port) + "/";

  // #half=never|always: whether the page refines through half size (it predicts the full image's
  // render time otherwise, which headless Chromium's virtual clock does not give).
  // #size=32x32 renders the run's own size (the default fills the window: below).
  ASSERT_EQ(chromium("--dump-dom", url + "#half=never,size=32x32", t / "plain.html"), 0)
      << read_file(t / "plain.html.log");
  const PageState plain = page_state(read_file(t / "plain.html"));
  ASSERT_EQ(chromium("--dump-dom", url + "#half=never", t / "window.html"), 0) << read_file(t / "window.html.log");
  const PageState window = page_state(read_file(t / "window.html"));
  // Exported points (scene frame) around the origin the cameras look at: #points=on draws them.
  std::string ply =
      "ply\nformat ascii 1.0\nelement vertex 27\nproperty float x\nproperty float y\nproperty float z\n"
      "end_header\n";
  for (int i = 0; i < 27; ++i)
    ply += std::to_string(0.2 * (i % 3 - 1)) + " " + std::to_string(0.2 * (i / 3 % 3 - 1)) + " " +
           std::to_string(0.2 * (i / 9 - 1)) + "\n";
  test::write_file(t / "run/points.ply", ply);
  test::write_file(t / "run/exports.json",
                   "[{\"frame\": \"scene\", \"points\": {\"path\": \"" + t / "run/points.ply" + "\"}}]");
  ASSERT_EQ(chromium("--dump-dom", url + "#half=never,size=32x32,points=on", t / "points.html"), 0)
      << read_file(t / "points.html.log");
  const PageState points = page_state(read_file(t / "points.html"));
  ASSERT_EQ(chromium("--dump-dom", url + "#drag=60,20", t / "drag.html"), 0) << read_file(t / "drag.html.log");
  const PageState dragged = page_state(read_file(t / "drag.html"));
  ASSERT_EQ(chromium("--dump-dom", url + "#half=always,size=32x32", t / "half.html"), 0)
      << read_file(t / "half.html.log");
  const PageState half = page_state(read_file(t / "half.html"));
  fs::create_directories("artifacts");
  const std::string shot = fs::absolute("artifacts/viewer.png").string();
  fs::remove(shot);
  ASSERT_EQ(chromium("--screenshot='" + shot + "'", url, t / "shot.out"), 0) << read_file(t / "shot.out.log");
  serving.reset();  // the server stops here

  // The page read the cameras (the pose is camera 0's), and images arrived and were drawn.
  const auto cams = session.cameras_json();
  std::string cam0;
  for (size_t i = 0; i < 12; ++i) {
    char b[32];
    std::snprintf(b, sizeof(b), "%.6f", cams.at("cameras")[0][i].get<double>());
    cam0 += (i ? "," : "") + std::string(b);
  }
  EXPECT_EQ(plain.pose, cam0);
  EXPECT_GE(plain.images, 1);
  // The view refines while it rests: quarter, then full size of the 32x32 run, or quarter, half,
  // then full.
  EXPECT_EQ(plain.drawn, "8x8 32x32");
  EXPECT_EQ(half.drawn, "8x8 16x16 32x32");
  // By default the view fills the window (420x360, less the bar: square like the run's camera) and
  // is rendered at half that size, quarter first, then drawn scaled up.
  EXPECT_EQ(window.shown_w, window.shown_h);
  EXPECT_GT(window.shown_w, 100);
  EXPECT_LE(window.shown_w, 420);
  const int full = static_cast<int>(std::lround(window.shown_w * 0.5)),
            quarter = std::max(8, static_cast<int>(std::lround(full * 0.25)));
  EXPECT_EQ(window.drawn, std::to_string(quarter) + "x" + std::to_string(quarter) + " " + std::to_string(full) + "x" +
                              std::to_string(full));
  // The exported points are drawn over the view: all 27 lie in front of camera 0, within its image.
  EXPECT_EQ(points.points_drawn, 27);
  EXPECT_EQ(plain.points_drawn, -1);  // without the checkbox (the plain page had no export yet)
  // A finished run: the training bar stays hidden (it was once shown by a CSS display that
  // overrode the hidden attribute).
  EXPECT_NE(read_file(t / "plain.html").find("id=\"livebar\" style=\"padding: 0 10px 6px; display: none;"),
            std::string::npos);
  // The drag moved the camera, and a view was drawn (the first camera's quarter-size answer may be
  // dropped as stale once the drag asked for the moved view).
  EXPECT_FALSE(dragged.pose.empty());
  EXPECT_NE(dragged.pose, plain.pose);
  EXPECT_GE(dragged.images, 1);
  // The screenshot: the 32x32 render sits under the bar, drawn at its size in a dark page; it is
  // not flat.
  ASSERT_TRUE(fs::exists(shot));
  const auto png = read_png(shot).to(torch::kFloat);
  EXPECT_GT(png.std().item<double>(), 5.0);
}
