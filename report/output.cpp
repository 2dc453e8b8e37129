#include "report/output.h"

#include <fcntl.h>
#include <fmt/format.h>
#include <stdio.h>
#include <unistd.h>

#include <signal.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <utility>
#include <vector>

#include "core/atomic_file.h"
#include "core/error.h"
#include "core/parallel.h"

namespace fs = std::filesystem;

namespace dropfit::report {

void OutputSet::add(const std::string& relative_path, std::string content) {
  files_[relative_path] = std::move(content);
}

namespace {

// True when `child` is `parent` or inside it, symbolic links resolved.
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

// A relative path of the OutputSet must stay below the output folder.
void check_relative(const std::string& relative) {
  const fs::path p(relative);
  bool ok = !relative.empty() && p.is_relative();
  for (const auto& part : p) ok = ok && part != ".." && part != ".";
  if (!ok) throw Error(fmt::format("output file name '{}' would leave the output folder", relative));
}

// Swaps two names atomically where the kernel can (renameat2 with
// RENAME_EXCHANGE); false when it cannot.
bool exchange(const fs::path& a, const fs::path& b) {
#ifdef RENAME_EXCHANGE
  return ::renameat2(AT_FDCWD, a.c_str(), AT_FDCWD, b.c_str(), RENAME_EXCHANGE) == 0;
#else
  (void)a;
  (void)b;
  return false;
#endif
}

// Removes a folder and everything in it, the files on several threads: on
// a journalling file system each removal may wait for the journal, and the
// waits overlap. Links inside are removed, never followed; what cannot be
// removed is left (as std::filesystem::remove_all with an error code would).
void remove_tree(const fs::path& root) {
  std::vector<fs::path> files;
  std::vector<std::pair<int, fs::path>> folders;
  std::error_code ec;
  for (auto it = fs::recursive_directory_iterator(root, ec); !ec && it != fs::recursive_directory_iterator();
       it.increment(ec)) {
    if (it->is_directory(ec) && !it->is_symlink(ec)) folders.emplace_back(it.depth(), it->path());
    else files.push_back(it->path());
  }
  parallel_for(files.size(), 8, [&](std::size_t k) {
    std::error_code ignore;
    fs::remove(files[k], ignore);
  });
  // Deepest first; then whatever is left the usual way.
  std::sort(folders.begin(), folders.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  std::error_code ignore;
  for (const auto& f : folders) fs::remove(f.second, ignore);
  fs::remove_all(root, ignore);
}

// Staging and old folders of `name` in `parent` (".NAME.staging-PID-N",
// ".NAME.old-PID-N") left by a run that was killed: those whose process is
// gone are removed. A live process's are left alone (it may be committing).
void remove_stale_staging(const fs::path& parent, const std::string& name) {
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(parent, ec)) {
    const std::string n = e.path().filename().string();
    for (const char* kind : {".staging-", ".old-"}) {
      const std::string prefix = "." + name + kind;
      if (n.size() <= prefix.size() || n.compare(0, prefix.size(), prefix) != 0) continue;
      const std::string rest = n.substr(prefix.size());
      const std::size_t dash = rest.find('-');
      long pid = 0;
      try {
        pid = std::stol(rest.substr(0, dash));
      } catch (const std::exception&) {
        continue;
      }
      if (pid <= 0 || (::kill(static_cast<pid_t>(pid), 0) == 0 || errno == EPERM)) continue;
      std::error_code ignore;
      fs::remove_all(e.path(), ignore);
    }
  }
}

}  // namespace

std::string output_source(const std::string& out_dir) {
  std::ifstream in(fs::path(out_dir) / kOutputMarker);
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("source: ", 0) == 0) return line.substr(8);
  return {};
}

std::vector<std::string> session_output_folders(const std::string& out_dir, const std::vector<std::string>& sessions) {
  std::vector<std::string> canonical, names(sessions.size());
  for (const auto& s : sessions) canonical.push_back(fs::weakly_canonical(fs::absolute(s)).string());
  std::set<std::string> taken;
  std::map<std::string, std::string> existing;  // session -> folder name, from the markers of earlier runs
  std::error_code ec;
  for (const auto& e : fs::directory_iterator(out_dir, ec)) {
    if (!e.is_directory(ec) || e.is_symlink(ec)) continue;
    const std::string name = e.path().filename().string();
    taken.insert(name);
    const std::string source = output_source(e.path().string());
    if (!source.empty()) existing.emplace(source, name);
  }
  // A session run before into this folder keeps its folder.
  for (std::size_t i = 0; i < sessions.size(); ++i)
    if (const auto it = existing.find(canonical[i]); it != existing.end()) names[i] = it->second;
  // The others: the session folder's name, or with as many of its parent
  // folders as make it unique ("a__demo", "b__demo"); "-2", "-3" last.
  auto suffix = [&](std::size_t i, std::size_t k) {  // the last k parts of session i's path, joined by "__"
    std::vector<std::string> parts;
    for (const auto& part : fs::path(canonical[i])) {
      const std::string p = part.string();
      if (!p.empty() && p != "/") parts.push_back(p);
    }
    if (parts.empty()) parts.push_back("session");
    std::string name = parts.back();
    for (std::size_t d = 2; d <= k && d <= parts.size(); ++d) name = parts[parts.size() - d] + "__" + name;
    return name;
  };
  const std::vector<std::string> assigned = names;
  for (std::size_t i = 0; i < sessions.size(); ++i) {
    if (!names[i].empty()) continue;
    // The shortest suffix that no other new session shares at that depth
    // and no existing folder holds.
    std::string name;
    for (std::size_t k = 1; k <= 64; ++k) {
      name = suffix(i, k);
      bool clash = taken.count(name) > 0;
      for (std::size_t j = 0; j < sessions.size() && !clash; ++j)
        clash = j != i && canonical[j] != canonical[i] && (assigned[j].empty() ? suffix(j, k) == name : assigned[j] == name);
      if (!clash || name == suffix(i, k + 1)) break;
    }
    const std::string base = name;
    for (int k = 2; taken.count(name); ++k) name = fmt::format("{}-{}", base, k);
    names[i] = name;
    taken.insert(name);
  }
  std::vector<std::string> out;
  for (const auto& n : names) out.push_back((fs::path(out_dir) / n).string());
  return out;
}

void OutputSet::commit(const std::string& out_dir, const std::vector<std::string>& protected_dirs) const {
  if (out_dir.empty()) throw Error("output folder: empty name");
  for (const auto& dir : protected_dirs) {
    if (is_within(out_dir, dir)) {
      throw Error(fmt::format("output folder '{}' is inside the session folder '{}'; a session is never written into",
                              out_dir, dir));
    }
    if (is_within(dir, out_dir)) {
      throw Error(fmt::format("output folder '{}' holds the session folder '{}'; the output folder is replaced whole, "
                              "so it must not hold a session",
                              out_dir, dir));
    }
  }
  for (const auto& [relative, content] : files_) check_relative(relative);

  // The target: absent, empty, or a folder an earlier commit wrote (it holds
  // the marker). Anything else is refused rather than replaced.
  const fs::path target = fs::absolute(fs::path(out_dir)).lexically_normal();
  const fs::path parent = target.parent_path();
  const std::string name = target.filename().string();
  if (name.empty() || name == "." || name == "..") {
    throw Error(fmt::format("output folder '{}': name a folder, not '{}'", out_dir, name));
  }
  std::error_code ec;
  const auto status = fs::symlink_status(target, ec);
  const bool exists = fs::exists(status);
  if (exists) {
    if (fs::is_symlink(status)) {
      throw Error(fmt::format("output folder '{}' is a symbolic link; name the folder itself", out_dir));
    }
    if (!fs::is_directory(status)) throw Error(fmt::format("output folder '{}' is a file, not a folder", out_dir));
    const bool empty = fs::is_empty(target, ec);
    if (!empty && !fs::is_regular_file(fs::symlink_status(target / kOutputMarker, ec))) {
      throw Error(fmt::format("output folder '{}' already holds files and no {} marker, so dropfit did not write "
                              "it; name a new or empty folder (a folder dropfit wrote is replaced whole)",
                              out_dir, kOutputMarker));
    }
  }
  fs::create_directories(parent, ec);
  if (ec || !fs::is_directory(parent)) {
    throw Error(fmt::format("{}: cannot create folder: {}", parent.string(),
                            ec ? ec.message() : "a file of that name is in the way"));
  }

  remove_stale_staging(parent, name);

  // Stage every file in a sibling folder, then swap it with the target: a
  // failure before the swap leaves the target as it was, and after it the
  // target holds exactly this set (no stale files of an earlier run).
  static std::atomic<unsigned> counter{0};
  const std::string tag = fmt::format("{}-{}", ::getpid(), counter++);
  const fs::path staging = parent / fmt::format(".{}.staging-{}", name, tag);
  const fs::path old = parent / fmt::format(".{}.old-{}", name, tag);
  auto discard = [&] {
    std::error_code ignore;
    fs::remove_all(staging, ignore);
  };
  try {
    fs::create_directory(staging, ec);
    if (ec) throw Error(fmt::format("{}: cannot create folder: {}", staging.string(), ec.message()));
    std::vector<std::pair<std::string, std::string_view>> staged;
    for (const auto& [relative, content] : files_) {
      const fs::path file = staging / relative;
      fs::create_directories(file.parent_path(), ec);
      if (ec || !fs::is_directory(file.parent_path())) {
        throw Error(fmt::format("{}: cannot create folder: {}", (target / relative).parent_path().string(),
                                ec ? ec.message() : "a file of that name is in the way"));
      }
      if (fs::is_directory(file)) throw Error(fmt::format("{}: a folder of that name is in the way", (target / relative).string()));
      staged.emplace_back(file.string(), content);
    }
    const std::string marker = "Written by dropfit. The next run into this folder replaces it whole.\n" +
                               (source_.empty() ? std::string() : "source: " + source_ + "\n");
    staged.emplace_back((staging / kOutputMarker).string(), marker);
    // Every file fsynced before the folder is swapped in, in batches (one
    // disk flush for many files).
    write_files_synced(staged);
    std::vector<std::string> folders;
    for (auto it = fs::recursive_directory_iterator(staging); it != fs::recursive_directory_iterator(); ++it)
      if (it->is_directory()) folders.push_back(it->path().string());
    folders.push_back(staging.string());
    sync_directories(folders);
  } catch (const fs::filesystem_error& e) {
    discard();
    throw Error(fmt::format("{}: cannot stage the results: {}", out_dir, e.code().message()));
  } catch (...) {
    discard();
    throw;
  }

  if (!exists) {
    fs::rename(staging, target, ec);
    if (ec) {
      discard();
      throw Error(fmt::format("{}: cannot move the results into place: {}", out_dir, ec.message()));
    }
  } else if (exchange(staging, target)) {
    remove_tree(staging);  // now the previous results
  } else {
    fs::rename(target, old, ec);
    if (ec) {
      discard();
      throw Error(fmt::format("{}: cannot move the previous results aside: {}", out_dir, ec.message()));
    }
    fs::rename(staging, target, ec);
    if (ec) {
      std::error_code ignore;
      fs::rename(old, target, ignore);
      discard();
      throw Error(fmt::format("{}: cannot move the results into place: {}", out_dir, ec.message()));
    }
    remove_tree(old);
  }
  sync_directory(parent.string());
}

void write_file_atomic(const std::string& path, const std::string& content) {
  dropfit::write_file_atomic(path, content);
}

}  // namespace dropfit::report
