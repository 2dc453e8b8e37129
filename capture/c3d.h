#pragma once
// A small reader of C3D files (the biomechanics binary format that Vicon,
// Qualisys, Kistler BioWare and others write), from the format's public
// description (c3d.org, "The C3D File Format User Guide"):
//
// - The file is 512-byte blocks. Block 1 is the header: byte 0 the first
//   parameter block (1-based), byte 1 the key 0x50, then 16-bit words:
//   points (word 2), analog measurements per point frame over all channels
//   (3), first and last frame (4, 5, 1-based), the maximum interpolation gap
//   (6), the point scale factor (words 7-8, a float: negative means the data
//   are floating point, its magnitude still scales integer residuals), the
//   first data block (9), analog samples per channel per point frame (10) and
//   the point frame rate (words 11-12, a float).
// - The parameter section: 4 bytes (two reserved, the number of parameter
//   blocks, the processor type 83 + n: 84 Intel, 85 DEC, 86 MIPS), then
//   records. A record: name length (int8; negative = locked, 0 = end), id
//   (int8; negative = a group, positive = a parameter of group -id), the
//   name, a 16-bit offset from the offset field to the next record (0 = last),
//   then for a group its description (length byte, text) and for a parameter
//   its type (-1 char, 1 byte, 2 int16, 4 float), dimension count, dimensions
//   (one byte each), the values (first dimension fastest), the description.
// - The data section: per point frame, every point's X Y Z and a fourth word
//   (integer files: low byte the residual in scale units, high byte the
//   camera mask; negative: the point is invalid), then analog samples per
//   frame x channels (sample-major). Integer files store int16 (analog
//   unsigned when ANALOG:FORMAT is "UNSIGNED"), floating-point files 32-bit
//   floats.
// - Byte order follows the processor: Intel and DEC little-endian, MIPS
//   big-endian; floats are IEEE except DEC's VAX F-floats (16-bit words
//   swapped, exponent bias 128 with the hidden bit after the point: the IEEE
//   reading of the swapped bytes is 4 times the value).
//
// The reader is bounded: every count and offset is checked against the file
// before anything is allocated or read, files beyond kMaxC3dBytes are
// refused, and every error is a dropfit::InputError naming the file (line 0)
// and the header word or GROUP:PARAMETER at fault. No error is a crash.
#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace dropfit::capture {

inline constexpr std::size_t kMaxC3dBytes = std::size_t{1} << 30;  // 1 GiB

enum class C3dProcessor { Intel = 84, Dec = 85, Mips = 86 };

struct C3dParameter {
  std::string group;  // upper case, as the file names them
  std::string name;
  int type = 0;           // -1 char, 1 byte, 2 int16, 4 float
  std::vector<int> dims;  // empty: a scalar
  std::vector<double> numbers;       // numeric types: every value, first dimension fastest
  std::vector<std::string> strings;  // char: one string per column of the first dimension, blanks trimmed
};

struct C3dFile {
  std::string path;
  C3dProcessor processor = C3dProcessor::Intel;
  bool float_data = false;     // point scale factor negative
  double point_scale = 1.0;    // the header's scale factor (signed as stored)
  double point_rate_hz = 0.0;  // header frame rate
  int first_frame = 1;         // 1-based
  int n_frames = 0;
  int n_points = 0;
  int n_analog_channels = 0;
  int analog_per_frame = 0;    // samples per channel per point frame
  std::vector<C3dParameter> parameters;
  // n_frames x (4 n_points): X Y Z in POINT:UNITS (integer files already
  // multiplied by the scale factor), then the residual; all four NaN where
  // the point is invalid.
  Eigen::MatrixXd points;
  // (n_frames analog_per_frame) x channels: the stored values (counts for
  // integer files), before ANALOG:OFFSET, SCALE and GEN_SCALE.
  Eigen::MatrixXd analog_stored;

  // The parameter GROUP:NAME (case-insensitive), or nullptr.
  const C3dParameter* find(std::string_view group, std::string_view name) const;
  // Analog sample rate: ANALOG:RATE when given, else point rate x analog_per_frame.
  double analog_rate_hz() const;
};

// Reads and checks a C3D file (at most kMaxC3dBytes).
C3dFile read_c3d(const std::string& path);
// The same from bytes in memory; `name` stands for the file in errors (for
// fuzzing and tests).
C3dFile parse_c3d(std::string_view bytes, const std::string& name);

// Analog channels in physical units: (stored - ANALOG:OFFSET[c]) x
// ANALOG:SCALE[c] x ANALOG:GEN_SCALE, for the 0-based `channels` (all when
// empty). Missing SCALE / OFFSET / GEN_SCALE entries are errors naming them.
Eigen::MatrixXd c3d_analog_scaled(const C3dFile& file, const std::vector<int>& channels = {});

}  // namespace dropfit::capture
