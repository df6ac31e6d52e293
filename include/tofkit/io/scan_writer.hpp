#pragma once
/// \file A streaming scan's files, written as the blocks of beams come (in
/// beam order) and finished at the end: scan.csv appended directly; the
/// point clouds' records kept in a working file until their count and bounds
/// are known, then written after their headers; the images' rows as they
/// finish (scan::ImageBuilder) into working files, from which the .npy files
/// and the PNGs (row by row, once the value span is known) are made. Every
/// file goes through the one writer (StreamingOutput): staged with the
/// command's other outputs, nothing left behind by a failure or a signal.
/// The bytes are those of the encode_* functions on the whole scan.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <set>
#include <span>
#include <string>
#include <vector>

#include "tofkit/scan/scanner.hpp"

namespace tofkit::io {

struct ScanWriterSettings {
  std::filesystem::path directory;
  /// Any of csv, png, npy, ply, pcd, las, view.
  std::set<std::string> outputs;
  double ambient_c = 0;  ///< the scan.csv column
  bool has_model = false;
  /// The JSON sidecar of a PNG plane (its text): file name, quantity, units,
  /// scale and offset.
  std::function<std::string(const std::string& file, const char* quantity, const char* units,
                            double scale, double offset)>
      sidecar;
};

class ScanWriter {
 public:
  /// `description`: the scan without beams (scan::describe_scan);
  /// `row_last_beam`: scan::row_last_beams of the pattern. Throws naming the
  /// file if an output is refused (before any beam is measured).
  ScanWriter(const scan::ScanResult& description, std::vector<std::size_t> row_last_beam,
             ScanWriterSettings settings);
  ~ScanWriter();
  ScanWriter(const ScanWriter&) = delete;
  ScanWriter& operator=(const ScanWriter&) = delete;

  /// The next block of beams (first_beam: its first beam's index; blocks in order).
  void add(std::size_t first_beam, std::span<const scan::BeamResult> beams);

  struct Summary {
    std::uint64_t beams = 0, points = 0, mixed = 0;
  };
  /// Writes the headers and what was held back, and stages every file.
  Summary finish();

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tofkit::io
