// ablenerf: the command-line entry point. Subcommands register themselves (command.h); this file
// turns what escapes them into one line on stderr and an exit code.
#include <torch/version.h>
#include <c10/util/Exception.h>
#include <malloc.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <iostream>
#include <string>

// Every section of the run configuration, so that every program knows them all
// (util/config_section.h: a section is registered by its header).
#include "data/data_config.h"
#include "eval/eval_config.h"
#include "model/compute_config.h"
#include "model/model_config.h"
#include "train/train_config.h"
#include "cli/command.h"
#include "kernels/cpu_features.h"
#include "kernels/cpu_parallel.h"
#include "util/errors.h"
#include "util/log.h"

namespace {

constexpr const char* kOutOfGpuMemory =
    "error: out of GPU memory: lower train.micro_batch (training) or eval.chunk (eval/render: --chunk), "
    "e.g. --set train.micro_batch=2048 or --chunk 4096";

// glibc's malloc serves blocks above a (moving) threshold with mmap and hands freed memory at the
// heap's top back to the system, so every training step's and render chunk's tensors arrive as
// fresh pages that the kernel faults in and zeroes (13% of a CPU training step's time in a perf
// profile of the demo preset). Keeping freed memory in the heap instead: training +10-20%,
// rendering +19% (`ablenerf bench --config configs/demo.toml --rays 512`, 2-core machine, 2026-11-23).
// Blocks of 32 MiB and more still come from mmap, and the heap is trimmed above 1 GiB free.
void keep_freed_memory() {
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 1 << 30);
}

// Restarts the program with OPENBLAS_CORETYPE set where OpenBLAS fell back to kernels far below
// the CPU's (kernels/cpu_parallel.h, blas_core_override): OpenBLAS reads the variable only when it
// is loaded. The same process (execv keeps the pid, so torchrun and c10d see no difference), the
// same arguments; the variable set stops a second restart. If the restart fails, the program goes
// on with OpenBLAS's own choice.
void restart_with_blas_core(char** argv) {
  const std::string core = ablenerf::blas_core_override();
  if (core.empty()) return;
  if (setenv("OPENBLAS_CORETYPE", core.c_str(), 1) != 0) return;
  execv("/proc/self/exe", argv);
}

}  // namespace

int main(int argc, char** argv) {
  using namespace ablenerf;
  restart_with_blas_core(argv);
  keep_freed_memory();
  flush_subnormals();  // before any thread starts (kernels/cpu_parallel.h)
  CLI::App app{"ablenerf: ABLE-NeRF (attention-based rendering with learnable embeddings) in C++"};
  app.set_version_flag(
      "--version", std::string("ablenerf ") + ABLENERF_VERSION + " (LibTorch " + std::to_string(TORCH_VERSION_MAJOR) +
                       "." + std::to_string(TORCH_VERSION_MINOR) + "." + std::to_string(TORCH_VERSION_PATCH) + ")");
  app.require_subcommand(1);
  auto& reg = cli::command_registry();
  std::sort(reg.begin(), reg.end(), [](const auto& a, const auto& b) { return a.order < b.order; });
  for (auto& spec : reg) {
    CLI::App* sub = app.add_subcommand(spec.name, spec.help);
    // Every command: how much of the log (util/log.h) reaches standard error.
    sub->add_flag_callback(
        "--quiet", [] { set_log_level(LogLevel::Warn); }, "Only warnings and errors (no progress)");
    sub->add_flag_callback(
        "--verbose", [] { set_log_level(LogLevel::Debug); }, "Also debugging detail");
    spec.setup(*sub);
  }
  try {
    if (!cpu_isa_cap_known())
      throw InputError(
          cpu_isa_cap_variable(), "",
          std::string("must be avx512, avx2 or baseline, got '") + std::getenv(cpu_isa_cap_variable()) + "'");
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return kExitBadInput;
  } catch (const cli::CommandExit& e) {
    if (!e.message().empty()) std::cerr << "error: " << e.message() << std::endl;
    return e.code();
  } catch (const InputError& e) {
    std::cerr << "error: " << e.what() << std::endl;
    return kExitBadInput;
  } catch (const EnvironmentError& e) {
    std::cerr << "error: " << e.what() << std::endl;
    return kExitEnvironment;
  } catch (const c10::OutOfMemoryError&) {
    std::cerr << kOutOfGpuMemory << std::endl;
    return kExitEnvironment;
  } catch (const c10::Error& e) {
    // Some allocation paths (cuBLAS workspaces, older LibTorch) raise a plain c10::Error.
    if (std::string(e.what()).find("CUDA out of memory") != std::string::npos) {
      std::cerr << kOutOfGpuMemory << std::endl;
      return kExitEnvironment;
    }
    std::cerr << "internal error: " << e.what_without_backtrace() << std::endl;
    return kExitInternal;
  } catch (const std::exception& e) {
    std::cerr << "internal error: " << e.what() << std::endl;
    return kExitInternal;
  }
  return kExitOk;
}
