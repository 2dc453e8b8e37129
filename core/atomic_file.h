#pragma once
// Files that are either whole or absent: the one write-then-rename helper of
// the project. Each write goes to a temporary file beside the target, is
// flushed to the disk (fsync), renamed over the target, and the folder's
// entry is flushed too, so that neither a crash nor a power cut leaves half
// a file under the final name. Errors are dropfit::Error naming the path.
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace dropfit {

// Creates the parent folders as needed, then writes `content` to `path`
// atomically (temporary name, fsync, rename, fsync of the folder).
void write_file_atomic(const std::string& path, std::string_view content);

// Writes a new file and fsyncs it, without the rename (for files inside a
// staging folder that is itself renamed into place).
void write_file_synced(const std::string& path, std::string_view content);

// Writes several new files (path, content) and fsyncs every one, as
// write_file_synced does one by one, but in batches: each file of a batch is
// written and its writeback started, then all are fsynced at once, so that
// one journal commit and one disk flush serve many files instead of one each.
// On a failure the files of the failing batch are removed and the error
// names the path.
void write_files_synced(const std::vector<std::pair<std::string, std::string_view>>& files);

// fsync of a folder, so that the names created or renamed in it persist.
void sync_directory(const std::string& path);

// sync_directory of every folder, all at once (one journal commit for all,
// as in write_files_synced); throws the first failure.
void sync_directories(const std::vector<std::string>& paths);

}  // namespace dropfit
