#pragma once
// Error types shared by every module.
//
// InputError is what bad user input raises: the CLI prints its one-line message
// ("FILE: FIELD: what is wrong") and exits with code 2.
// EnvironmentError is what the machine raises when it cannot do what a correct command asks (a full
// disk, a folder without write permission, no GPU memory left): the CLI prints its one-line message,
// which names the fix, and exits with code 1.
// Anything else that escapes is an internal error (exit code 1, "internal error: ...").
#include <stdexcept>
#include <string>
#include <string_view>

namespace ablenerf {

class InputError : public std::runtime_error {
 public:
  InputError(const std::string& file, const std::string& field, const std::string& what)
      : std::runtime_error(compose(file, field, what)), file_(file), field_(field) {}
  const std::string& file() const { return file_; }
  const std::string& field() const { return field_; }

 private:
  static std::string compose(const std::string& file, const std::string& field, const std::string& what) {
    std::string s = file.empty() ? std::string("<input>") : file;
    if (!field.empty()) s += ": " + field;
    return s + ": " + what;
  }
  std::string file_, field_;
};

// "SUBJECT: WHAT (FIX)", e.g. "runs/a/checkpoint.pt: cannot write: No space left on device (disk
// full? free space in runs/a)". `fix` may be empty.
class EnvironmentError : public std::runtime_error {
 public:
  EnvironmentError(const std::string& subject, const std::string& what, const std::string& fix)
      : std::runtime_error(subject + ": " + what + (fix.empty() ? std::string() : " (" + fix + ")")),
        subject_(subject) {}
  const std::string& subject() const { return subject_; }

 private:
  std::string subject_;
};

// Untrusted text (a name or token read from an input file) quoted in an error message: control
// bytes and DEL become '?' so the message stays one line, and at most `max_chars` bytes are kept
// ("..." marks a cut). Other bytes (UTF-8 file names) are kept as they are.
inline std::string printable(std::string_view s, size_t max_chars) {
  std::string out;
  for (const char c : s.substr(0, max_chars)) {
    const auto u = static_cast<unsigned char>(c);
    out += (u < 0x20 || u == 0x7f) ? '?' : c;
  }
  if (s.size() > max_chars) out += "...";
  return out;
}

// Exit codes of the CLI.
constexpr int kExitOk = 0;
constexpr int kExitInternal = 1;
constexpr int kExitEnvironment = 1;
constexpr int kExitBadInput = 2;
constexpr int kExitInterrupted = 130;

}  // namespace ablenerf
