#pragma once
// Internal to capture/: the force-file readers behind read_force (io.cpp)
// and capture/force_io.h.
#include <array>
#include <fstream>
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
// byte-order mark, converted to UTF-8; CR LF or LF line ends. Errors name
// the file (and the line of a bad UTF-16 sequence, or of a NUL byte).
std::vector<Line> read_text_lines(const std::string& path);

// The same lines one at a time, so that a force export's data section is
// parsed as it is read and never held as text: a UTF-8 file is read through
// a stream buffer; a UTF-16 one (BioWare's Unicode export) is converted
// whole first.
class LineStream {
 public:
  explicit LineStream(const std::string& path);
  // The next line into `line` (its 1-based number and text); false at the end.
  bool next(Line& line);

 private:
  std::string path_;
  std::ifstream in_;
  std::string decoded_;  // a UTF-16 file as UTF-8
  std::size_t at_ = 0;   // read position in decoded_
  bool utf16_ = false;
  int number_ = 0;
};

// The column header of a force text export and the lines before it (the
// free header), read from `stream` until a line whose first field is
// "Time(s)" / "Time (s)" (eight-channel) or begins "abs time" (BioWare); a
// BioWare header is followed by its units line, read too. The data rows
// stay in the stream.
struct ForceTextHead {
  std::vector<Line> lines;  // the free header, the column header, (BioWare) the units line
  std::size_t header = 0;   // index of the column header in lines
  bool bioware = false;
};
ForceTextHead read_force_text_head(const std::string& path, LineStream& stream);

// The trigger of an export that carries none (BioWare text, C3D), from
// rec.data (its layout set): pretrigger_samples and the `trigger` text,
// from plate.pretrigger_fraction when the manifest gives it, else from the
// data (trigger_sample_from_data), which an InputError naming `path`
// reports when it finds no crossing.
void set_trigger(ForceRecord& rec, const ForcePlateSpec& plate, const std::string& path);

// The two text layouts, from the head and the data rows left in `rows`.
ForceRecord read_eight_channel(const std::string& path, const ForceTextHead& head, LineStream& rows,
                               const ForcePlateSpec& plate);
ForceRecord read_bioware(const std::string& path, const ForceTextHead& head, LineStream& rows,
                         const ForcePlateSpec& plate);

// The data rows of a force text export, one at a time: blank lines at the
// end are allowed, a blank line followed by more data is an InputError
// naming it.
class DataRows {
 public:
  DataRows(const std::string& path, LineStream& rows) : path_(path), rows_(rows) {}
  bool next(Line& line);

 private:
  const std::string& path_;
  LineStream& rows_;
  int blank_line_ = 0;  // number of the first blank line of a run, 0 when none
};

}  // namespace dropfit::capture::detail
