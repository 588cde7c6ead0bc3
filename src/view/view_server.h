#pragma once
// `ablenerf view`'s HTTP server (cpp-httplib, Debian's libcpp-httplib-dev), loopback by default:
//   GET /             the viewer page (view/viewer_page.cpp: everything it needs is in it)
//   GET /api/cameras  ViewSession::cameras_json()
//   GET /api/render?pose=P&w=W&h=H[&mode=rgb|depth|error][&look=N|mean]   a PNG of the view from pose P (12
//                     numbers, comma-separated: the row-major camera-to-world 3x4 in the scene
//                     frame); error mode names the camera it compared in X-Nearest-Camera
//   GET /api/state    {"step" (of the weights shown; -1 before the first), "live", "paused"}
//   GET /api/log      the run's log.jsonl records as a JSON array (loss and held-out PSNR curves)
//   GET /api/control?action=pause|resume|save   a run being trained (`train --view`) only
// A bad request gets 400 and one line naming the parameter; the server goes on. Connections are
// served by a thread pool (a slow client holds one thread, not the server); renders take turns.
#include <memory>
#include <string>
#include <thread>

#include "view/view_session.h"

namespace httplib {
class Server;
}

namespace ablenerf {

class ViewServer {
 public:
  // `control`: the live run's buttons (null for a finished run).
  ViewServer(ViewSession& session, std::string host, int port, LiveControl* control = nullptr);
  ~ViewServer();
  ViewServer(const ViewServer&) = delete;
  ViewServer& operator=(const ViewServer&) = delete;

  // Binds the socket (port 0: any free port) and returns the port; EnvironmentError with the fix
  // when the address is taken or not ours.
  int bind();
  // Serves until stop() (from any thread); call after bind().
  void run();
  void stop();

 private:
  ViewSession& session_;
  LiveControl* control_;
  std::string host_;
  int port_;
  std::unique_ptr<httplib::Server> server_;
};

// Serves a bound ViewServer on a thread of its own for this object's lifetime: the destructor stops
// the server and joins the thread, on every path out of the scope (exceptions, failed assertions).
class ServingThread {
 public:
  explicit ServingThread(ViewServer& server);
  ~ServingThread();
  ServingThread(const ServingThread&) = delete;
  ServingThread& operator=(const ServingThread&) = delete;

 private:
  ViewServer& server_;
  std::thread thread_;
};

// The viewer page's HTML (with its script and style inline).
const char* viewer_page_html();

}  // namespace ablenerf
