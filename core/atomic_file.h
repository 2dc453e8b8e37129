#pragma once
// Files that are either whole or absent: the one write-then-rename helper of
// the project. Each write goes to a temporary file beside the target, is
// flushed to the disk (fsync), renamed over the target, and the folder's
// entry is flushed too, so that neither a crash nor a power cut leaves half
// a file under the final name. Errors are dropfit::Error naming the path.
#include <string>
#include <string_view>

namespace dropfit {

// Creates the parent folders as needed, then writes `content` to `path`
// atomically (temporary name, fsync, rename, fsync of the folder).
void write_file_atomic(const std::string& path, std::string_view content);

// Writes a new file and fsyncs it, without the rename (for files inside a
// staging folder that is itself renamed into place).
void write_file_synced(const std::string& path, std::string_view content);

// fsync of a folder, so that the names created or renamed in it persist.
void sync_directory(const std::string& path);

}  // namespace dropfit
