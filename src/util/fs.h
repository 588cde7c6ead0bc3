#pragma once
// Reading and writing whole files: the one atomic writer and the one reader of the project.
#include <cstddef>
#include <string>
#include <string_view>

#include "util/errors.h"

namespace ablenerf {

// Writes `bytes` to `path` through a temporary file in the same folder (atomic_temp_prefix(path)
// followed by the process id and a counter), flushed to the device (fsync) and renamed over `path`:
// readers never see a partial file, a kill at any moment leaves the old or the new file, and an
// earlier file at `path` survives a failure. The temporary is removed when the write fails.
// Throws EnvironmentError naming `path` and the fix (write_error) when it cannot write.
void write_file_atomic(const std::string& path, std::string_view bytes);

// "PATH.tmp": the start of the names of write_file_atomic's temporaries for `path`. A process
// killed mid-write leaves such a file behind; the real file is intact.
std::string atomic_temp_prefix(const std::string& path);

// The whole file, byte for byte (binary-safe). Throws InputError(path, "", "cannot read: ...")
// when it is missing, a folder or unreadable.
std::string read_file(const std::string& path);
// At most the first `max_bytes` bytes of the file (fewer when it is shorter), with read_file's
// messages.
std::string read_file_prefix(const std::string& path, size_t max_bytes);
// Opens `path` read-only and returns the descriptor (the caller closes it), with read_file's
// messages when it is missing, a folder or unreadable.
int open_for_reading(const std::string& path);

// Creates the folder (and its parents). A file in the way is an InputError; a folder that cannot
// be created (permissions, full disk) an EnvironmentError.
void ensure_dir(const std::string& path);

// The EnvironmentError for a failed write of `path` with errno `err`: "PATH: cannot write: REASON
// (FIX)", where FIX names what to do (free space in the folder, make it writable, ...).
EnvironmentError write_error(const std::string& path, int err);

}  // namespace ablenerf
