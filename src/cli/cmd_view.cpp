// `ablenerf view`: a local web viewer of a trained run (view/view_server.h). Built only when
// Debian's libcpp-httplib-dev is present (ABLENERF_HAVE_VIEW); otherwise the command says so.
#include <csignal>
#include <iostream>
#include <memory>

#include "cli/command.h"
#include "cli/common.h"
#include "util/errors.h"
#ifdef ABLENERF_HAVE_VIEW
#include "view/view_server.h"
#endif

namespace ablenerf::cli {
namespace cmd_view {

struct ViewArgs {
  std::string run, host = "127.0.0.1", device = "auto";
  int port = 7007;
};

#ifdef ABLENERF_HAVE_VIEW
ViewServer* g_server = nullptr;
extern "C" void on_signal(int) {
  if (g_server) g_server->stop();
}
#endif

void run(const ViewArgs& a) {
#ifdef ABLENERF_HAVE_VIEW
  ViewSession session(a.run, parse_device(a.device));
  ViewServer server(session, a.host, a.port);
  const int port = server.bind();
  std::cout << "view: http://" << a.host << ":" << port << "/  (" << a.run << "; Ctrl-C stops)" << std::endl;
  g_server = &server;
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  server.run();
  g_server = nullptr;
#else
  throw EnvironmentError("view", "this build has no viewer",
                         "install libcpp-httplib-dev and rebuild (scripts/setup.sh)");
#endif
}

void setup(CLI::App& app) {
  auto a = std::make_shared<ViewArgs>();
  app.add_option("--run", a->run, "Run folder written by `ablenerf train`")->required();
  app.add_option("--port", a->port, "TCP port (0 = any free port)")->capture_default_str()->check(CLI::Range(0, 65535));
  app.add_option("--host", a->host, "Address to listen on (loopback by default; 0.0.0.0 opens it to the network)")
      ->capture_default_str();
  app.add_option("--device", a->device, "cpu, cuda, cuda:N or auto (cuda when available)");
  app.callback([a] { run(*a); });
}

}  // namespace cmd_view
ABLENERF_COMMAND("view", 45, "Serve a local web viewer of a run: fly through the scene in a browser", cmd_view::setup);
}  // namespace ablenerf::cli
