// Finding a trial's force file by its name or, failing that, by its content;
// see capture/force_io.h.
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "capture/force_io.h"
#include "capture/text_io.h"
#include "core/error.h"

namespace dropfit::capture {
namespace {

namespace fs = std::filesystem;

// The first `n` bytes of a file (fewer when it is shorter); empty when it
// cannot be read.
std::string head_bytes(const fs::path& path, std::size_t n) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return {};
  std::string bytes(n, '\0');
  in.read(bytes.data(), static_cast<std::streamsize>(n));
  bytes.resize(static_cast<std::size_t>(in.gcount()));
  return bytes;
}

// UTF-16 text (byte-order mark FF FE or FE FF) as bytes with the zero high
// bytes dropped: enough to recognise ASCII column headers.
std::string as_ascii(std::string bytes) {
  if (bytes.size() >= 2 && ((bytes[0] == '\xFF' && bytes[1] == '\xFE') || (bytes[0] == '\xFE' && bytes[1] == '\xFF'))) {
    bytes.erase(0, 2);
    bytes.erase(std::remove(bytes.begin(), bytes.end(), '\0'), bytes.end());
  }
  return bytes;
}

}  // namespace

ForceFileKind force_file_kind(const std::string& path) {
  const std::string head = head_bytes(path, 64 * 1024);
  // C3D: byte 1 of the header block is the key 0x50; header word 3 counts
  // the analog samples per point frame (0: a file of markers only).
  if (head.size() >= 512 && static_cast<unsigned char>(head[1]) == 0x50) {
    const auto word = [&](int k, bool big) {
      const auto b0 = static_cast<unsigned char>(head[2 * k - 2]), b1 = static_cast<unsigned char>(head[2 * k - 1]);
      return big ? (b0 << 8) | b1 : (b1 << 8) | b0;
    };
    // The processor type is in the parameter section; a count is non-zero in
    // either byte order exactly when it is non-zero.
    return word(3, false) != 0 ? ForceFileKind::C3d : ForceFileKind::None;
  }
  const std::string text = as_ascii(head);
  std::size_t at = 0;
  while (at < text.size()) {
    std::size_t end = text.find_first_of("\r\n", at);
    if (end == std::string::npos) end = text.size();
    std::string_view line = detail::trim(std::string_view(text).substr(at, end - at));
    if (line.size() >= 3 && line.substr(0, 3) == "\xEF\xBB\xBF") line.remove_prefix(3);
    const std::string_view first = line.substr(0, line.find('\t'));
    if (detail::iequals(first, "Time(s)") || detail::iequals(first, "Time (s)")) return ForceFileKind::KistlerText;
    if (detail::iequals_prefix(first, "abs time")) return ForceFileKind::BioWareText;
    at = end + 1;
  }
  return ForceFileKind::None;
}

std::string find_force_file(const std::string& trial_dir) {
  const fs::path dir(trial_dir);
  std::error_code ec;
  // The contract's names first: force.txt, force.c3d (any case of the extension).
  std::vector<fs::path> named;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name == "force.txt" || detail::iequals(name, "force.c3d")) named.push_back(it->path());
  }
  std::sort(named.begin(), named.end());
  if (named.size() > 1)
    throw InputError(trial_dir, 0, 0, "force.txt",
                     fmt::format("the trial folder holds both {} and {}: remove the one not meant",
                                 named[0].filename().string(), named[1].filename().string()));
  if (named.size() == 1) return named[0].string();
  // Else the one file whose content is a force export, whatever the lab
  // named it (BioWare: the trial's name, .txt or .C3D). Marker tables,
  // offsets and markers-only C3D files are not force files.
  std::vector<fs::path> found;
  ec.clear();
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (!it->is_regular_file(ec)) continue;
    const std::string ext = it->path().extension().string();
    if (!detail::iequals(ext, ".txt") && !detail::iequals(ext, ".c3d") && !detail::iequals(ext, ".tsv")) continue;
    if (force_file_kind(it->path().string()) != ForceFileKind::None) found.push_back(it->path());
  }
  std::sort(found.begin(), found.end());
  if (found.size() > 1)
    throw InputError((dir / "force.txt").string(), 0, 0, "",
                     fmt::format("file not found, and more than one force export lies beside it: {} and {}; keep "
                                 "one (or name it force.txt or force.c3d)",
                                 found[0].filename().string(), found[1].filename().string()));
  if (found.size() == 1) return found[0].string();
  return (dir / "force.txt").string();
}

}  // namespace dropfit::capture
