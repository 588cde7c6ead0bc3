// `ablenerf train`: trains a model on a dataset into a run folder (see train/trainer.h).
#include <filesystem>
#include <iostream>

#include "cli/command.h"
#include "cli/common.h"
#include "run/run_folder.h"
#include "train/distributed.h"
#include "train/trainer.h"
#include "util/duration.h"
#include "util/errors.h"
#include "util/log.h"
#ifdef ABLENERF_HAVE_VIEW

#include "view/view_server.h"
#include "train/train_config.h"
#endif

namespace ablenerf::cli {
namespace cmd_train {

struct TrainArgs {
  std::string data, out, device = "auto", backend = "gloo";
  bool resume = false;
  int64_t max_steps = -1;
  double time_limit = 0;
  std::string time_budget;
  double dist_timeout = 120;
  bool view = false;
  bool json = false;
  int view_port = 7007;
  std::string view_host = "127.0.0.1";
  int downscale = 0;  // 0: the config's data.downscale
  int64_t steps = 0;  // 0: the config's train.steps
  ConfigOptions cfg;
};

// `--view`: trains with the live viewer attached (view/view_server.h). Weights are copied to the
// viewer between steps only when a render asked for them; pause blocks the training thread there.
TrainResult train_with_view(const Config& config, TrainOptions o, const TrainArgs& a) {
#ifdef ABLENERF_HAVE_VIEW
  if (o.dist) throw InputError("train", "--view", "the viewer attaches to one process, not to a group");
  struct Live {
    std::unique_ptr<ViewSession> session;
    LiveControl control;
  };
  auto live = std::make_shared<Live>();
  o.between_steps = [live](Trainer& t) {
    if (live->session) view_between_steps(t, *live->session, live->control);
  };
  Trainer trainer(config, o);
  trainer.setup();
  live->session = std::make_unique<ViewSession>(a.out, o.device, /*live=*/true);
  ViewServer server(*live->session, a.view_host, a.view_port, &live->control);
  const int port = server.bind();
  std::cout << "train: live view at http://127.0.0.1:" << port << "/" << std::endl;
  const ServingThread serving(server);
  return trainer.run();
#else
  (void)config, (void)o, (void)a;
  throw EnvironmentError("train", "--view: this build has no viewer",
                         "install libcpp-httplib-dev and rebuild (scripts/setup.sh)");
#endif
}

void setup(CLI::App& app) {
  auto a = std::make_shared<TrainArgs>();
  app.add_option("--data", a->data, "Dataset folder (Blender or transforms.json format)");
  app.add_option("--out", a->out, "Run folder to create (or continue with --resume)")->required();
  app.add_flag("--resume", a->resume, "Continue the run in --out from its last checkpoint (starts fresh if none)");
  app.add_option("--device", a->device, "cpu, cuda, cuda:N or auto (cuda when available)");
  // Two kinds of length, in two groups of --help: the run's (its schedule is laid over it) and this
  // invocation's (a pause: the run continues with --resume where it stopped).
  const std::string run_length = "The run's length (the learning-rate schedule is laid over it)";
  const std::string pause = "Stopping this invocation early (checkpointed; continue with --resume)";
  app.add_option("--stop-after", a->max_steps, "Checkpoint and stop after this many steps of this invocation")
      ->group(pause);
  app.add_option("--time-limit", a->time_limit,
                 "Checkpoint and stop after this many seconds of training in this invocation (0 = none)")
      ->check(CLI::NonNegativeNumber)
      ->group(pause);
  app.add_option("--time-budget", a->time_budget,
                 "Train for this wall-clock budget with the schedule laid out over it (train.time_budget_s): "
                 "5m, 90s, 2h, 1h30m or seconds")
      ->group(run_length);
  app.add_flag("--view", a->view, "Serve the live viewer while training (--host, --port): see `ablenerf view`");
  add_json_flag(app, a->json);
  app.add_option("--port", a->view_port, "Port of --view's viewer (0 = any free port)")
      ->capture_default_str()
      ->check(CLI::Range(0, 65535));
  app.add_option("--host", a->view_host, "Address --view's viewer listens on (loopback unless you say otherwise)")
      ->capture_default_str();
  add_old_spelling(app, "--view-port", "--port", a->view_port);
  app.add_option("--downscale", a->downscale, "Train on the images reduced N times (data.downscale)")
      ->check(CLI::PositiveNumber);
  app.add_option("--steps", a->steps, "Train this many steps in all (train.steps; with --time-budget, a cap)")
      ->check(CLI::PositiveNumber)
      ->group(run_length);
  app.add_option("--dist-backend", a->backend, "c10d backend when launched with WORLD_SIZE: gloo (CPU) or nccl (CUDA)");
  app.add_option("--dist-timeout", a->dist_timeout, "Seconds before a stalled collective fails (a dead rank)");
  a->cfg.add_to(app, false);
  app.footer(
      "Multi-process: set torchrun's RANK, WORLD_SIZE, LOCAL_RANK, MASTER_ADDR, MASTER_PORT (see README).\n"
      "With --resume and no --config or --preset, the run's own config.toml is used.");
  app.callback([a] {
    Config config;
    const bool no_preset = a->cfg.config_path.empty() && a->cfg.preset.empty();
    const bool from_run = a->resume && no_preset && std::filesystem::exists(a->out + "/config.toml");
    if (from_run) {
      config = RunFolder::open(a->out).config;
      for (const auto& s : a->cfg.sets) config.set(s);
      config.validate();
    } else {
      config = resolve_config(a->cfg);
    }
    const bool defaults = no_preset && !from_run;
    // The flags that stand for config keys, after the config (and --set) they override.
    if (a->downscale > 0) config.set("data.downscale=" + std::to_string(a->downscale));
    if (a->steps > 0) config.set("train.steps=" + std::to_string(a->steps));
    if (a->downscale > 0 || a->steps > 0) config.validate();
    if (!a->time_budget.empty()) {
      const auto seconds = parse_duration(a->time_budget);
      if (!seconds || *seconds <= 0)
        throw InputError("train", "--time-budget",
                         "expected a duration such as 5m, 90s, 2h or 1h30m, got '" + a->time_budget + "'");
      config.get<TrainConfig>().time_budget_s = *seconds;
      config.validate();
    }
    TrainOptions o;
    o.data_dir = a->data;
    o.out_dir = a->out;
    o.resume = a->resume;
    o.max_steps_this_run = a->max_steps;
    o.time_limit_s = a->time_limit;
    o.device = parse_device(a->device);
    const DistEnv env = DistEnv::from_environment();
    if (env.local_rank > 0 && o.device.is_cuda()) o.device = torch::Device(torch::kCUDA, env.local_rank);
    std::unique_ptr<Distributed> dist;
    // A group whenever a launcher set WORLD_SIZE (torchrun does so for one process too, so a
    // one-process launch runs the same collective code path as a larger one).
    if (env.world_size > 1 || env.launched) {
      dist = Distributed::join(env, a->backend, a->dist_timeout);
      o.dist = dist.get();
    }
    // Without a preset the program's defaults are the paper's model and schedule: said once, after
    // every argument was accepted (a refused one stays the only line).
    if (defaults && env.rank == 0)
      log_warn(
          "train: no --preset or --config: the paper's model and schedule (the blender preset); for your own "
          "photos use --preset capture (or capture_gpu on a GPU)");
    install_interrupt_handlers();
    // Exit codes other than 0 and 2 travel as CommandExit so that `dist` (the process group) is
    // destroyed on the way out.
    TrainResult r;
    try {
      r = a->view ? train_with_view(config, o, *a) : train(config, o);
    } catch (const TrainingDiverged& e) {
      throw CommandExit(kExitDiverged, e.what());
    }
    if (r == TrainResult::Interrupted) throw CommandExit(kExitInterrupted);
    if (env.rank == 0) {
      const std::string& run = a->out;
      if (a->json) {
        std::cout << nlohmann::json{{"run", run},
                                    {"next",
                                     {"ablenerf eval --run " + run,
                                      "ablenerf render --run " + run + " --path orbit --out " + run + "/orbit.mp4",
                                      "ablenerf export --run " + run + " --mesh " + run + "/mesh.ply",
                                      "ablenerf view --run " + run}}}
                         .dump()
                  << std::endl;
        return;
      }
      std::cout << "train: run written to " << run << "\nnext:\n  ablenerf eval --run " << run
                << "\n  ablenerf render --run " << run << " --path orbit --out " << run << "/orbit.mp4"
                << "\n  ablenerf export --run " << run << " --mesh " << run << "/mesh.ply"
                << "\n  ablenerf view --run " << run << std::endl;
    }
  });
}

}  // namespace cmd_train
ABLENERF_COMMAND("train", 20, "Train a model on a dataset (writes a run folder: config, checkpoints, log, weights)",
                 cmd_train::setup);
}  // namespace ablenerf::cli
