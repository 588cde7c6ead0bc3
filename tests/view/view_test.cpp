// The web viewer's server (view/view_server.h) over real HTTP on loopback: the page, the cameras,
// renders equal to eval's renderer for the same pose, bad requests answered with 400 and one line
// while the server goes on, two clients at once, and a client that sends half a request and stalls.
#include <arpa/inet.h>
#include <gtest/gtest.h>
#include <httplib.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <torch/torch.h>
#include <unistd.h>

#include <cstring>
#include <nlohmann/json.hpp>
#include <thread>

#include "eval/eval_fixtures.h"
#include "eval/renderer.h"
#include "test_util.h"
#include "util/image_io.h"
#include "view/view_server.h"
#include "eval/eval_config.h"

using namespace ablenerf;

namespace {

// A served tiny run: session, server on a free loopback port, serving thread.
class Served {
 public:
  Served() {
    test::make_tiny_scene(dir_ / "scene", 2, 2, 16, 16, false);
    test::make_tiny_run(dir_ / "run", dir_ / "scene");
    session_ = std::make_unique<ViewSession>(dir_ / "run", torch::kCPU);
    server_ = std::make_unique<ViewServer>(*session_, "127.0.0.1", 0);
    port_ = server_->bind();
    serving_ = std::make_unique<ServingThread>(*server_);
  }
  int port() const { return port_; }
  ViewSession& session() { return *session_; }
  const test::TempDir& dir() const { return dir_; }

 private:
  test::TempDir dir_;
  std::unique_ptr<ViewSession> session_;
  std::unique_ptr<ViewServer> server_;
  int port_ = 0;
  std::unique_ptr<ServingThread> serving_;  // declared last: stopped and joined first
};

std::string pose_text(const std::vector<float>& p) {
  std::string s;
  for (size_t i = 0; i < p.size(); ++i) s += (i ? "," : "") + std::to_string(p[i]);
  return s;
}

// Camera `i` of the session's cameras_json() as render_png takes it.
std::array<float, 12> camera_c2w(const ViewSession& session, int i) {
  const auto pose = session.cameras_json().at("cameras")[i].get<std::vector<float>>();
  std::array<float, 12> c2w{};
  std::copy(pose.begin(), pose.end(), c2w.begin());
  return c2w;
}

// A PNG body decoded (through a file: the codec reads files).
torch::Tensor decode(const std::string& png, const test::TempDir& dir) {
  test::write_file(dir / "got.png", png);
  return read_png(dir / "got.png");
}

}  // namespace

TEST(ViewServer, PageCamerasAndARenderEqualToTheRenderers) {
  Served s;
  httplib::Client cli("127.0.0.1", s.port());
  auto page = cli.Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->body.find("<canvas"), std::string::npos);
  EXPECT_NE(page->body.find("/api/render"), std::string::npos);
  EXPECT_EQ(page->body.find("http://"), std::string::npos);  // nothing fetched from elsewhere
  EXPECT_EQ(page->body.find("https://"), std::string::npos);

  auto cams = cli.Get("/api/cameras");
  ASSERT_TRUE(cams);
  ASSERT_EQ(cams->status, 200);
  const auto j = nlohmann::json::parse(cams->body);
  EXPECT_EQ(j.at("cameras").size(), 4u);  // 2 train + 2 test
  EXPECT_EQ(j.at("width"), 16);
  const auto pose = j.at("cameras")[2].get<std::vector<float>>();

  auto r = cli.Get(("/api/render?w=16&h=12&pose=" + pose_text(pose)).c_str());
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(r->get_header_value("Content-Type"), "image/png");
  const auto got = decode(r->body, s.dir());
  ASSERT_EQ(got.sizes(), (std::vector<int64_t>{12, 16, 3}));
  // The same view through the renderer directly: the dataset's focal at this width, centred.
  AbleNerf model = load_run_model(RunFolder::open(s.dir() / "run"), torch::kCPU);
  model->eval();
  Intrinsics k;
  k.width = 16, k.height = 12;
  k.fx = k.fy = j.at("fx").get<double>();
  k.cx = 8, k.cy = 6;
  auto c2w = torch::tensor(std::vector<float>(pose.begin(), pose.end())).reshape({3, 4});
  const torch::NoGradGuard no_grad;
  const RunFolder run = RunFolder::open(s.dir() / "run");
  const RenderResult ref = render_image(model, c2w, k, run.scene().near, run.scene().far,
                                        run.config.get<EvalConfig>().chunk, ForwardOptions{}, torch::kCPU);
  EXPECT_LE((got.to(torch::kInt) - to_uint8(ref.rgb).to(torch::kInt)).abs().max().item<int>(), 0);
  // Depth mode: a colour map of the same size.
  auto d = cli.Get(("/api/render?w=16&h=12&mode=depth&pose=" + pose_text(pose)).c_str());
  ASSERT_TRUE(d);
  ASSERT_EQ(d->status, 200);
  EXPECT_EQ(decode(d->body, s.dir()).sizes(), (std::vector<int64_t>{12, 16, 3}));
}

TEST(ViewServer, ErrorModeIsEvalsErrorMapOfTheNearestCamera) {
  Served s;
  httplib::Client cli("127.0.0.1", s.port());
  const auto j = nlohmann::json::parse(cli.Get("/api/cameras")->body);
  // Camera 2 is the first test view (2 train, then 2 test): nudged a little, it is still nearest.
  auto pose = j.at("cameras")[2].get<std::vector<float>>();
  pose[3] += 0.05f;
  auto r = cli.Get(("/api/render?w=16&h=16&mode=error&pose=" + pose_text(pose)).c_str());
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200) << r->body;
  EXPECT_EQ(r->get_header_value("X-Nearest-Camera"), "2");
  // eval's own error map of test view 0 (its loader, its renderer, its colour map).
  const auto e = test::run_cli("eval --run " + s.dir() / "run" + " --max-images 1");
  ASSERT_EQ(e.exit_code, 0) << e.output;
  const auto want = read_png(s.dir() / "run/eval/test/r_0_error.png").to(torch::kInt);
  const auto got = decode(r->body, s.dir()).to(torch::kInt);
  ASSERT_EQ(got.sizes(), want.sizes());
  EXPECT_LE((got - want).abs().max().item<int>(), 1);
  EXPECT_GT(want.to(torch::kFloat).std().item<double>(), 1.0);  // the map is not flat
}

TEST(ViewServer, BadRequestsGet400AndOneLineAndTheServerGoesOn) {
  Served s;
  httplib::Client cli("127.0.0.1", s.port());
  const std::string ok_pose = "1,0,0,0,0,1,0,0,0,0,1,4";
  const std::pair<std::string, std::string> bad[] = {
      {"/api/render?w=16&h=16", "pose"},
      {"/api/render?w=16&h=16&pose=1,0,0,0,0,1,0,0,0,0,1", "pose"},
      {"/api/render?w=16&h=16&pose=1,0,0,0,0,1,0,0,0,0,1,nan", "pose"},
      {"/api/render?w=16&h=16&pose=1,0,0,0,0,1,0,0,0,0,1,4,5", "pose"},
      {"/api/render?w=5&h=16&pose=" + ok_pose, "w"},
      {"/api/render?w=16&h=99999&pose=" + ok_pose, "h"},
      {"/api/render?w=16.5&h=16&pose=" + ok_pose, "w"},
      {"/api/render?w=16&h=16&mode=normals&pose=" + ok_pose, "mode"},
  };
  for (const auto& [url, field] : bad) {
    auto r = cli.Get(url.c_str());
    ASSERT_TRUE(r) << url;
    EXPECT_EQ(r->status, 400) << url;
    EXPECT_NE(r->body.find(field), std::string::npos) << url << ": " << r->body;
    EXPECT_EQ(std::count(r->body.begin(), r->body.end(), '\n'), 1) << r->body;
  }
  auto missing = cli.Get("/nothing/here");
  ASSERT_TRUE(missing);
  EXPECT_EQ(missing->status, 404);
  auto good = cli.Get(("/api/render?w=8&h=8&pose=" + ok_pose).c_str());
  ASSERT_TRUE(good);
  EXPECT_EQ(good->status, 200);
}

TEST(ViewServer, TwoClientsAndAStalledOne) {
  Served s;
  // A client that sends half a request line and then nothing: it holds one connection.
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  ASSERT_GE(fd, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<uint16_t>(s.port()));
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ASSERT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)), 0);
  const char half[] = "GET /api/render?w=16";
  ASSERT_EQ(::send(fd, half, sizeof(half) - 1, 0), static_cast<ssize_t>(sizeof(half) - 1));
  // Meanwhile two clients render at once; both get their image.
  const std::string url = "/api/render?w=16&h=16&pose=1,0,0,0,0,1,0,0,0,0,1,4";
  int status[2] = {0, 0};
  std::thread a([&] {
    httplib::Client c("127.0.0.1", s.port());
    if (auto r = c.Get(url.c_str())) status[0] = r->status;
  });
  std::thread b([&] {
    httplib::Client c("127.0.0.1", s.port());
    if (auto r = c.Get(url.c_str())) status[1] = r->status;
  });
  a.join();
  b.join();
  EXPECT_EQ(status[0], 200);
  EXPECT_EQ(status[1], 200);
  ::close(fd);  // a closed tab
  httplib::Client c("127.0.0.1", s.port());
  auto after = c.Get("/api/cameras");
  ASSERT_TRUE(after);
  EXPECT_EQ(after->status, 200);
}

// The run's latest points export comes back in the scene frame (exports.json says the file is in
// the capture's coordinates), evenly thinned to the asked count; a run without exports has none,
// and the endpoint answers the same.
// Per-photo colour in the viewer: cameras_json lists the training photos; a render with photo 0's
// look is the mean look's render through photo 0's colour map (set by hand: red halved, green +0.2),
// to within the PNG's rounding; a look out of range, or on a run without per-photo colour (also
// through the server), is refused naming "look".
TEST(ViewServer, LooksOfTheTrainingPhotos) {
  test::TempDir dir;
  test::make_tiny_scene(dir / "scene", 2, 2, 16, 16, false);
  test::make_tiny_run(dir / "run", dir / "scene");
  {
    AbleNerf model = load_run_model(RunFolder::open(dir / "run"), torch::kCPU);
    model->enable_photo_colour(2);
    const torch::NoGradGuard no_grad;
    // The maps applied are each photo's delta minus the mean delta: +D for photo 0, -D for photo 1.
    auto d = torch::zeros({3, 4});
    d[0][0] = -0.5;  // red x 0.5
    d[1][3] = 0.2;   // green + 0.2
    model->photo_colour()->parameter().copy_(torch::stack({d, -d}));
    save_weights(model, dir / "run/weights.pt");
  }
  ViewSession session(dir / "run", torch::kCPU);
  const auto j = session.cameras_json();
  ASSERT_EQ(j.at("looks").size(), 2u);
  const auto pose = j.at("cameras")[2].get<std::vector<float>>();
  std::array<float, 12> c2w{};
  std::copy(pose.begin(), pose.end(), c2w.begin());
  const auto mean = decode(session.render_png(c2w, 16, 12, ViewMode::Rgb), dir).to(torch::kFloat) / 255;
  const auto look = decode(session.render_png(c2w, 16, 12, ViewMode::Rgb, nullptr, 0), dir).to(torch::kInt);
  const auto expected =
      to_uint8((mean * torch::tensor({0.5f, 1.0f, 1.0f}) + torch::tensor({0.0f, 0.2f, 0.0f})).clamp(0, 1))
          .to(torch::kInt);
  EXPECT_LE((look - expected).abs().max().item<int>(), 1);  // the mean render was rounded once already
  EXPECT_GT((look - (mean * 255).round().to(torch::kInt)).abs().max().item<int>(), 10);  // and it differs
  const auto refused = [&](int which) {
    try {
      session.render_png(c2w, 16, 12, ViewMode::Rgb, nullptr, which);
    } catch (const InputError& e) {
      return std::string(e.what());
    }
    return std::string("not refused");
  };
  EXPECT_NE(refused(2).find("look"), std::string::npos);

  Served plain;  // a run without per-photo colour
  EXPECT_TRUE(plain.session().cameras_json().at("looks").empty());
  httplib::Client cli("127.0.0.1", plain.port());
  auto r = cli.Get(("/api/render?w=16&h=12&look=0&pose=" + pose_text(pose)).c_str());
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 400);
  EXPECT_NE(r->body.find("look"), std::string::npos) << r->body;
  r = cli.Get(("/api/render?w=16&h=12&look=mean&pose=" + pose_text(pose)).c_str());
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, 200) << r->body;
}

// Appearance codes in the viewer: a run with codes only (no colour maps) offers the training
// photos' looks, each rendered with its own code (opposite codes set by hand: the two looks differ
// from each other and from the mean look).
TEST(ViewServer, LooksOfAppearanceCodes) {
  test::TempDir dir;
  test::make_tiny_scene(dir / "scene", 2, 2, 16, 16, false);
  test::make_tiny_run(dir / "run", dir / "scene");
  torch::manual_seed(6);
  const auto v = torch::randn({test::tiny_model_config().get<ModelConfig>().width}) * 3;
  test::give_run_appearance_codes(dir / "run", torch::stack({v, -v}));
  ViewSession session(dir / "run", torch::kCPU);
  ASSERT_EQ(session.cameras_json().at("looks").size(), 2u);
  const auto c2w = camera_c2w(session, 2);
  const auto render = [&](int look) {
    return decode(session.render_png(c2w, 16, 12, ViewMode::Rgb, nullptr, look), dir).to(torch::kInt);
  };
  const auto mean = render(-1), first = render(0), second = render(1);
  EXPECT_GT((first - mean).abs().max().item<int>(), 2);
  EXPECT_GT((first - second).abs().max().item<int>(), 2);
  EXPECT_THROW(render(2), InputError);
}

// The live view (`train --view`) takes the trainer's weights each time it renders: a trainer's
// model with per-photo parameters (colour maps, appearance codes) hands over the scene's weights and
// the view shows the mean look, rendered as the trainer's model renders it.
TEST(ViewServer, LiveWeightsFromATrainerWithPerPhotoParameters) {
  test::TempDir dir;
  test::make_tiny_scene(dir / "scene", 2, 2, 16, 16, false);
  test::make_tiny_run(dir / "run", dir / "scene");
  AbleNerf trained = load_run_model(RunFolder::open(dir / "run"), torch::kCPU);
  trained->enable_photo_colour(2);
  trained->enable_appearance_code(2);
  ViewSession live(dir / "run", torch::kCPU, /*live=*/true);
  ASSERT_NO_THROW(live.set_weights(trained, 7));
  EXPECT_EQ(live.weights_step(), 7);
  ViewSession saved(dir / "run", torch::kCPU);  // the same weights, read from the run
  const auto c2w = camera_c2w(saved, 1);
  EXPECT_EQ(live.render_png(c2w, 16, 12, ViewMode::Rgb), saved.render_png(c2w, 16, 12, ViewMode::Rgb));
}

TEST(ViewServer, ExportedPointsInTheSceneFrame) {
  test::TempDir t;
  test::make_tiny_scene(t / "scene", 2, 2, 16, 16, false);
  test::make_tiny_run(t / "run", t / "scene");
  {
    const ViewSession none(t / "run", torch::kCPU);
    EXPECT_EQ(none.points_json(10).at("count"), 0);
    EXPECT_TRUE(none.points_json(10).at("points").empty());
  }
  // A scene frame that is not the identity: x_scene = 2 R (x - c), R a quarter turn about z.
  SceneFrame frame = RunFolder::open(t / "run").scene();
  frame.rotation = {0, -1, 0, 1, 0, 0, 0, 0, 1};
  frame.centre = {1.0, 0.5, -0.25};
  frame.scale = 2.0;
  test::write_file(t / "run/scene.json", frame.to_json());
  const std::vector<std::array<double, 3>> pts{{0, 0, 0}, {1, 2, 3}, {-1, 0.5, 2}, {4, 4, 4}, {0.5, -0.5, 1}};
  std::string ply =
      "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
      "end_header\n";
  for (const auto& p : pts)
    ply += std::to_string(p[0]) + " " + std::to_string(p[1]) + " " + std::to_string(p[2]) + "\n";
  test::write_file(t / "run/points.ply", ply);
  test::write_file(t / "run/exports.json", "[{\"frame\": \"capture\", \"points\": {\"path\": \"" +
                                               t / "run/points.ply" + "\", \"count\": 5}}]");
  const ViewSession session(t / "run", torch::kCPU);
  const auto j = session.points_json(3);  // 5 points to at most 3: every second one
  EXPECT_EQ(j.at("count"), 5);
  const auto flat = j.at("points").get<std::vector<float>>();
  ASSERT_EQ(flat.size(), 9u);
  for (size_t k = 0; k < 3; ++k) {
    const auto& p = pts[2 * k];
    // By hand: d = p - c; R d = (-d_y, d_x, d_z); times 2.
    const double dx = p[0] - 1.0, dy = p[1] - 0.5, dz = p[2] + 0.25;
    EXPECT_NEAR(flat[3 * k + 0], 2 * -dy, 1e-5) << k;
    EXPECT_NEAR(flat[3 * k + 1], 2 * dx, 1e-5) << k;
    EXPECT_NEAR(flat[3 * k + 2], 2 * dz, 1e-5) << k;
  }
  // Over HTTP: a served run without exports answers an empty list.
  Served s;
  httplib::Client cli("127.0.0.1", s.port());
  auto r = cli.Get("/api/points");
  ASSERT_TRUE(r);
  ASSERT_EQ(r->status, 200);
  EXPECT_EQ(nlohmann::json::parse(r->body).at("count"), 0);
}
