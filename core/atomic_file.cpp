#include "core/atomic_file.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>

#include "core/error.h"
#include "core/parallel.h"

namespace fs = std::filesystem;

namespace dropfit {
namespace {

std::string system_error_text() { return std::strerror(errno); }

// Threads that wait on fsyncs together (they use no CPU while they wait).
constexpr int kSyncThreads = 8;

// Creates `path` and writes all of `content` to it; returns the open file
// (the caller syncs and closes it), or throws (the partial file removed).
int create_and_write(const fs::path& path, std::string_view content) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw Error(fmt::format("{}: cannot create: {}", path.string(), system_error_text()));
  const char* p = content.data();
  size_t left = content.size();
  while (left > 0) {
    const ssize_t n = ::write(fd, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      const std::string failure = system_error_text();
      ::close(fd);
      std::error_code ignore;
      fs::remove(path, ignore);
      throw Error(fmt::format("{}: cannot write: {}", path.string(), failure));
    }
    p += n;
    left -= static_cast<size_t>(n);
  }
  return fd;
}

// fsync and close of a file create_and_write returned; the error text, empty
// on success.
std::string sync_and_close(int fd) {
  std::string failure;
  if (::fsync(fd) != 0) failure = system_error_text();
  if (::close(fd) != 0 && failure.empty()) failure = system_error_text();
  return failure;
}

// Writes all of `content` to a new file and fsyncs it; throws on any failure
// (the partial file is removed).
void write_and_sync(const fs::path& path, std::string_view content) {
  const int fd = create_and_write(path, content);
  const std::string failure = sync_and_close(fd);
  if (!failure.empty()) {
    std::error_code ignore;
    fs::remove(path, ignore);
    throw Error(fmt::format("{}: cannot write: {}", path.string(), failure));
  }
}

}  // namespace

void sync_directory(const std::string& path) {
  const int fd = ::open(path.empty() ? "." : path.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) throw Error(fmt::format("{}: cannot open folder: {}", path, system_error_text()));
  const int rc = ::fsync(fd);
  const int err = rc != 0 ? errno : 0;
  ::close(fd);
  // Some file systems cannot sync a folder (EINVAL); the data is synced anyway.
  if (rc != 0 && err != EINVAL) throw Error(fmt::format("{}: cannot sync folder: {}", path, std::strerror(err)));
}

void sync_directories(const std::vector<std::string>& paths) {
  std::vector<std::string> failures(paths.size());
  parallel_for(paths.size(), kSyncThreads, [&](std::size_t k) {
    try {
      sync_directory(paths[k]);
    } catch (const std::exception& e) {
      failures[k] = e.what();
    }
  });
  for (const auto& f : failures)
    if (!f.empty()) throw Error(f);
}

void write_file_synced(const std::string& path, std::string_view content) { write_and_sync(path, content); }

void write_files_synced(const std::vector<std::pair<std::string, std::string_view>>& files) {
  // Batches bound the files held open at once (well under the usual limit
  // of 1024 descriptors).
  constexpr std::size_t kBatch = 64;
  for (std::size_t first = 0; first < files.size(); first += kBatch) {
    const std::size_t last = std::min(files.size(), first + kBatch);
    std::vector<int> fds;
    auto remove_batch = [&] {
      std::error_code ignore;
      for (std::size_t i = first; i < last; ++i) fs::remove(files[i].first, ignore);
    };
    try {
      for (std::size_t i = first; i < last; ++i) {
        fds.push_back(create_and_write(files[i].first, files[i].second));
        // Start the writeback now; the fsync below waits for it. A file
        // system that cannot is synced by the fsync alone.
        (void)::sync_file_range(fds.back(), 0, 0, SYNC_FILE_RANGE_WRITE);
      }
    } catch (...) {
      for (int fd : fds) ::close(fd);
      remove_batch();
      throw;
    }
    // The fsyncs at once, on threads that only wait: ext4 (and other
    // journalling file systems) serve concurrent fsyncs with one journal
    // commit, where one after another each waits for its own.
    std::vector<std::string> failures(fds.size());
    parallel_for(fds.size(), kSyncThreads, [&](std::size_t k) { failures[k] = sync_and_close(fds[k]); });
    std::string failure, failed_path;
    for (std::size_t k = 0; k < fds.size() && failure.empty(); ++k)
      if (!failures[k].empty()) failure = failures[k], failed_path = files[first + k].first;
    if (!failure.empty()) {
      remove_batch();
      throw Error(fmt::format("{}: cannot write: {}", failed_path, failure));
    }
  }
}

void write_file_atomic(const std::string& path, std::string_view content) {
  static std::atomic<unsigned> counter{0};
  const fs::path target(path);
  const fs::path parent = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code ec;
  fs::create_directories(parent, ec);
  if (ec || !fs::is_directory(parent)) {
    throw Error(fmt::format("{}: cannot create folder: {}", parent.string(),
                            ec ? ec.message() : "a file of that name is in the way"));
  }
  if (fs::is_directory(target)) throw Error(fmt::format("{}: a folder of that name is in the way", path));
  const fs::path temp = parent / fmt::format(".{}.tmp-{}-{}", target.filename().string(), ::getpid(), counter++);
  write_and_sync(temp, content);
  fs::rename(temp, target, ec);
  if (ec) {
    std::error_code ignore;
    fs::remove(temp, ignore);
    throw Error(fmt::format("{}: cannot rename into place: {}", path, ec.message()));
  }
  sync_directory(parent.string());
}

}  // namespace dropfit
