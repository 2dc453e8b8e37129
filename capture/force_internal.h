#pragma once
// Internal to capture/: the force-file readers behind read_force (io.cpp)
// and capture/force_io.h.
#include <array>
#include <string>
#include <vector>

#include "core/session.h"
#include "capture/text_io.h"

namespace dropfit::capture::detail {

inline constexpr std::array<const char*, 8> kForceEightChannels = {"Fx12", "Fx34", "Fy14", "Fy23",
                                                                   "Fz1",  "Fz2",  "Fz3",  "Fz4"};
inline constexpr std::array<const char*, 8> kForceResultants = {"Fx", "Fy", "Fz", "Mx", "My", "Mz", "Ax", "Ay"};

// Largest force text file read (a 1000 Hz, 16-plate export of an hour is
// far below it).
inline constexpr std::size_t kMaxForceTextBytes = std::size_t{512} << 20;

// Every line of a text file: UTF-8 (optional BOM) or UTF-16 LE/BE with its
// byte-order mark, converted to UTF-8; CR LF, CR or LF line ends. Errors
// name the file (and the line of a bad UTF-16 sequence).
std::vector<Line> read_text_lines(const std::string& path);

// The trigger of an export that carries none (BioWare text, C3D), from
// rec.data (its layout set): pretrigger_samples and the `trigger` text,
// from plate.pretrigger_fraction when the manifest gives it, else from the
// data (trigger_sample_from_data), which an InputError naming `path`
// reports when it finds no crossing.
void set_trigger(ForceRecord& rec, const ForcePlateSpec& plate, const std::string& path);

// The two text layouts, from the lines and the index of the column header.
ForceRecord read_eight_channel(const std::string& path, const std::vector<Line>& lines, std::size_t header,
                               const ForcePlateSpec& plate);
ForceRecord read_bioware(const std::string& path, const std::vector<Line>& lines, std::size_t header,
                         const ForcePlateSpec& plate);

}  // namespace dropfit::capture::detail
