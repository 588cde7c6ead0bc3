#include "view/view_server.h"

#include <httplib.h>

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <sstream>

#include "util/errors.h"
#include "util/fs.h"

namespace ablenerf {

namespace {

// A request parameter as a finite number; InputError naming it otherwise.
double number_param(const std::string& text, const std::string& name) {
  const char* s = text.c_str();
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(s, &end);
  if (end == s || *end != '\0' || errno == ERANGE || !std::isfinite(v))
    throw InputError("request", name, "expected a finite number, got '" + printable(text, 40) + "'");
  return v;
}

int side_param(const httplib::Request& req, const char* name) {
  if (!req.has_param(name)) throw InputError("request", name, "missing");
  const double v = number_param(req.get_param_value(name), name);
  if (v != std::floor(v) || v < kViewMinSide || v > kViewMaxSide)
    throw InputError("request", name,
                     "must be a whole number of pixels from " + std::to_string(kViewMinSide) + " to " +
                         std::to_string(kViewMaxSide));
  return static_cast<int>(v);
}

std::array<float, 12> pose_param(const httplib::Request& req) {
  if (!req.has_param("pose")) throw InputError("request", "pose", "missing");
  std::array<float, 12> out{};
  std::stringstream in(req.get_param_value("pose"));
  std::string item;
  size_t n = 0;
  while (std::getline(in, item, ',')) {
    if (n == 12) throw InputError("request", "pose", "expected 12 numbers");
    out[n++] = static_cast<float>(number_param(item, "pose"));
  }
  if (n != 12) throw InputError("request", "pose", "expected 12 numbers");
  return out;
}

void bad_request(httplib::Response& res, const std::string& message) {
  res.status = 400;
  res.set_content(message + "\n", "text/plain");
}

}  // namespace

ViewServer::ViewServer(ViewSession& session, std::string host, int port, LiveControl* control)
    : session_(session),
      control_(control),
      host_(std::move(host)),
      port_(port),
      server_(std::make_unique<httplib::Server>()) {
  auto& s = *server_;
  s.Get("/api/state", [this](const httplib::Request&, httplib::Response& res) {
    const nlohmann::json j{{"step", session_.weights_step()},
                           {"live", session_.live()},
                           {"paused", control_ ? control_->paused() : false}};
    res.set_content(j.dump(), "application/json");
  });
  s.Get("/api/log", [this](const httplib::Request&, httplib::Response& res) {
    // Complete lines only: the trainer may be appending one right now.
    nlohmann::json out = nlohmann::json::array();
    std::string text;
    try {
      text = read_file(session_.run().log_path());
    } catch (const std::exception&) {
    }
    std::istringstream in(text);
    std::string line;
    while (std::getline(in, line)) {
      if (in.eof()) break;  // no newline yet: being written
      const auto j = nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false);
      if (!j.is_discarded()) out.push_back(j);
    }
    res.set_content(out.dump(), "application/json");
  });
  s.Get("/api/control", [this](const httplib::Request& req, httplib::Response& res) {
    if (!control_) return bad_request(res, "request: action: the run is not being trained here (train --view)");
    const std::string a = req.get_param_value("action");
    if (a == "pause")
      control_->pause();
    else if (a == "resume")
      control_->resume();
    else if (a == "save")
      control_->request_save();
    else
      return bad_request(res, "request: action: must be pause, resume or save");
    res.set_content("{\"ok\": true}", "application/json");
  });
  s.Get("/", [](const httplib::Request&, httplib::Response& res) { res.set_content(viewer_page_html(), "text/html"); });
  s.Get("/api/cameras", [this](const httplib::Request&, httplib::Response& res) {
    res.set_content(session_.cameras_json().dump(), "application/json");
  });
  s.Get("/api/points", [this](const httplib::Request&, httplib::Response& res) {
    res.set_content(session_.points_json(kViewMaxPoints).dump(), "application/json");
  });
  s.Get("/api/render", [this](const httplib::Request& req, httplib::Response& res) {
    try {
      const auto pose = pose_param(req);
      const int w = side_param(req, "w"), h = side_param(req, "h");
      ViewMode mode = ViewMode::Rgb;
      if (req.has_param("mode")) {
        const std::string m = req.get_param_value("mode");
        if (m == "depth")
          mode = ViewMode::Depth;
        else if (m == "error")
          mode = ViewMode::Error;
        else if (m != "rgb")
          throw InputError("request", "mode", "must be rgb, depth or error");
      }
      int look = -1;  // a training photo's look (per-photo colour), -1 = the mean
      if (req.has_param("look") && req.get_param_value("look") != "mean") {
        const double v = number_param(req.get_param_value("look"), "look");
        if (v != std::floor(v) || v < 0 || v > 1e9)
          throw InputError("request", "look", "expected mean or a training photo's index");
        look = static_cast<int>(v);
      }
      int camera = -1;
      res.set_content(session_.render_png(pose, w, h, mode, &camera, look), "image/png");
      if (camera >= 0) res.set_header("X-Nearest-Camera", std::to_string(camera));
      res.set_header("Cache-Control", "no-store");
    } catch (const InputError& e) {
      bad_request(res, e.what());
    }
  });
  s.set_exception_handler([](const httplib::Request&, httplib::Response& res, std::exception_ptr ep) {
    std::string what = "internal error";
    try {
      std::rethrow_exception(ep);
    } catch (const std::exception& e) {
      what = e.what();
    } catch (...) {
    }
    res.status = 500;
    res.set_content(printable(what, 200) + "\n", "text/plain");
  });
  // A slow or silent client is dropped after this long instead of holding a thread forever.
  s.set_read_timeout(10, 0);
  s.set_write_timeout(10, 0);
}

ViewServer::~ViewServer() { stop(); }

int ViewServer::bind() {
  if (port_ == 0) {
    port_ = server_->bind_to_any_port(host_.c_str());
    if (port_ < 0) throw EnvironmentError("view", "cannot bind " + host_, "is it an address of this machine?");
  } else if (!server_->bind_to_port(host_.c_str(), port_)) {
    throw EnvironmentError("view", "cannot bind " + host_ + ":" + std::to_string(port_),
                           "port in use or not ours: pick another with --port, or 0 for any free one");
  }
  return port_;
}

void ViewServer::run() { server_->listen_after_bind(); }

void ViewServer::stop() {
  if (server_) server_->stop();
}

ServingThread::ServingThread(ViewServer& server) : server_(server), thread_([&server] { server.run(); }) {}

ServingThread::~ServingThread() {
  server_.stop();
  thread_.join();
}

}  // namespace ablenerf
