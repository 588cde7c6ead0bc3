#pragma once
// Subcommand registry: each src/cli/cmd_*.cpp registers its subcommand with a static
// ABLENERF_COMMAND(...) so that commands live in their own files and main.cpp stays generic.
// Each cmd_NAME.cpp keeps its helpers in namespace cmd_NAME, not an anonymous one: the unity build
// (CMakeLists.txt) compiles several command files as one translation unit.
#include <CLI/CLI.hpp>

#include <exception>
#include <functional>
#include <string>
#include <vector>

namespace ablenerf::cli {

// Thrown by a command that ends the process with an exit code other than 0 and 2 (interrupted,
// diverged). main() returns `code` after the stack has unwound, so destructors run (a process
// group's among them); `message`, when not empty, is printed first as "error: MESSAGE".
class CommandExit : public std::exception {
 public:
  explicit CommandExit(int code, std::string message = "") : code_(code), message_(std::move(message)) {}
  int code() const { return code_; }
  const std::string& message() const { return message_; }
  const char* what() const noexcept override { return message_.c_str(); }

 private:
  int code_;
  std::string message_;
};

struct CommandSpec {
  std::string name;
  std::string help;
  int order;                             // position in --help
  std::function<void(CLI::App&)> setup;  // adds options and a callback
};

// Every registered subcommand (command.cpp), in registration order.
std::vector<CommandSpec>& command_registry();

struct CommandRegistrar {
  explicit CommandRegistrar(CommandSpec spec) { command_registry().push_back(std::move(spec)); }
};

// Adds the repeated `--set section.key=value`, `--config FILE` and `--preset NAME` (cli/presets.h)
// handling shared by commands; --config and --preset exclude each other.
struct ConfigOptions {
  std::string config_path;
  std::string preset;
  std::vector<std::string> sets;
  void add_to(CLI::App& app, bool config_required);
};

}  // namespace ablenerf::cli

#define ABLENERF_CAT2(a, b) a##b
#define ABLENERF_CAT(a, b) ABLENERF_CAT2(a, b)
#define ABLENERF_COMMAND(name, order, help, setup_fn)                                       \
  static const ::ablenerf::cli::CommandRegistrar ABLENERF_CAT(ablenerf_cmd_, __COUNTER__) { \
    ::ablenerf::cli::CommandSpec { name, help, order, setup_fn }                            \
  }
