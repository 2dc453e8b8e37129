#include "report/output.h"

#include <fmt/format.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>

#include "core/error.h"

namespace fs = std::filesystem;

namespace dropfit::report {

void OutputSet::add(const std::string& relative_path, std::string content) {
  files_[relative_path] = std::move(content);
}

namespace {
bool is_within(const fs::path& child, const fs::path& parent) {
  const auto c = fs::weakly_canonical(child);
  const auto p = fs::weakly_canonical(parent);
  auto ci = c.begin();
  for (auto pi = p.begin(); pi != p.end(); ++pi, ++ci) {
    if (pi->empty()) continue;  // trailing separator
    if (ci == c.end() || *ci != *pi) return false;
  }
  return true;
}
}  // namespace

void OutputSet::commit(const std::string& out_dir, const std::vector<std::string>& protected_dirs) const {
  for (const auto& dir : protected_dirs) {
    if (is_within(out_dir, dir)) {
      throw Error(fmt::format("output folder '{}' is inside the session folder '{}'; a session is never written into",
                              out_dir, dir));
    }
  }
  // Two phases, so that a failure leaves nothing behind: every folder and
  // temporary file first, then the renames into place.
  std::vector<std::pair<fs::path, fs::path>> staged;  // temporary, final
  auto discard = [&staged] {
    std::error_code ignore;
    for (const auto& [temp, target] : staged) fs::remove(temp, ignore);
  };
  try {
    for (const auto& [relative, content] : files_) {
      const fs::path target = fs::path(out_dir) / relative;
      std::error_code ec;
      fs::create_directories(target.parent_path(), ec);
      if (ec || !fs::is_directory(target.parent_path())) {
        throw Error(fmt::format("{}: cannot create folder: {}", target.parent_path().string(),
                                ec ? ec.message() : "a file of that name is in the way"));
      }
      if (fs::is_directory(target)) throw Error(fmt::format("{}: a folder of that name is in the way", target.string()));
      const fs::path temp = target.string() + fmt::format(".tmp-{}", ::getpid());
      staged.emplace_back(temp, target);
      std::ofstream out(temp, std::ios::binary | std::ios::trunc);
      out.write(content.data(), static_cast<std::streamsize>(content.size()));
      out.flush();
      if (!out) throw Error(fmt::format("{}: cannot write", temp.string()));
    }
  } catch (...) {
    discard();
    throw;
  }
  for (const auto& [temp, target] : staged) {
    std::error_code ec;
    fs::rename(temp, target, ec);
    if (ec) {
      discard();
      throw Error(fmt::format("{}: cannot rename into place: {}", target.string(), ec.message()));
    }
  }
}

void write_file_atomic(const std::string& path, const std::string& content) {
  const fs::path target(path);
  std::error_code ec;
  if (target.has_parent_path()) {
    fs::create_directories(target.parent_path(), ec);
    if (ec) throw Error(fmt::format("{}: cannot create folder: {}", target.parent_path().string(), ec.message()));
  }
  const fs::path temp = target.string() + fmt::format(".tmp-{}", ::getpid());
  {
    std::ofstream out(temp, std::ios::binary | std::ios::trunc);
    if (!out) throw Error(fmt::format("{}: cannot write", temp.string()));
    out.write(content.data(), static_cast<std::streamsize>(content.size()));
    out.flush();
    if (!out) {
      fs::remove(temp, ec);
      throw Error(fmt::format("{}: write failed", temp.string()));
    }
  }
  fs::rename(temp, target, ec);
  if (ec) {
    fs::remove(temp, ec);
    throw Error(fmt::format("{}: cannot rename into place", target.string()));
  }
}

}  // namespace dropfit::report
