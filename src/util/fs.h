#pragma once
// Small filesystem helpers: atomic writes and readable failures.
#include <functional>
#include <string>

namespace ablenerf {

// Writes a file through `writer(tmp_path)` then renames tmp -> path, so readers never see a
// partial file and an earlier version survives a failure. `writer` must throw on failure;
// the temporary file is removed then. Also fsyncs the file before the rename.
void atomic_write(const std::string& path, const std::function<void(const std::string&)>& writer);

// Convenience: atomically write a string.
void atomic_write_text(const std::string& path, const std::string& text);

// Reads a whole file; throws InputError(path, "", "cannot read: ...") on failure.
std::string read_text_file(const std::string& path);

// Creates the directory (and parents); throws InputError on failure.
void ensure_dir(const std::string& path);

}  // namespace ablenerf
