#include "core/atomic_file.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <filesystem>

#include "core/error.h"

namespace fs = std::filesystem;

namespace dropfit {
namespace {

std::string system_error_text() { return std::strerror(errno); }

// Writes all of `content` to a new file and fsyncs it; throws on any failure
// (the partial file is removed).
void write_and_sync(const fs::path& path, std::string_view content) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw Error(fmt::format("{}: cannot create: {}", path.string(), system_error_text()));
  const char* p = content.data();
  size_t left = content.size();
  std::string failure;
  while (left > 0) {
    const ssize_t n = ::write(fd, p, left);
    if (n < 0) {
      if (errno == EINTR) continue;
      failure = system_error_text();
      break;
    }
    p += n;
    left -= static_cast<size_t>(n);
  }
  if (failure.empty() && ::fsync(fd) != 0) failure = system_error_text();
  if (::close(fd) != 0 && failure.empty()) failure = system_error_text();
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

void write_file_synced(const std::string& path, std::string_view content) { write_and_sync(path, content); }

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
