#pragma once
/// \file The validation matrix run on a virtual rangefinder: each row names a
/// quantitative figure of a document (reference/validation_matrix.csv), the
/// quantity that a twin run produces for it, the document's value and a band;
/// the runner computes every quantity by calling the experiment code
/// (paper_study, paper_method, thesis_protocol, thesis_line_scan, the
/// characterization protocols, scan_memory, the link budget) through a
/// registry from quantity id to function, and says which rows fall in band.
/// One experiment run serves every row that needs it. No I/O: the matrix is
/// parsed by io/validation_matrix.hpp, the outputs are written by the app.

#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "tofkit/device/device_config.hpp"
#include "tofkit/ranging/raw_measurement.hpp"

namespace tofkit::experiments {

/// Was the row's figure used to choose a twin parameter (calibration), or never (held out)?
enum class ValidationRole { kCalibration, kHeldOut };
/// Whose method produced the twin's value: the document's own (counted in the
/// band statistics) or tofkit's (reported beside it, not counted).
enum class ValidationMethod { kDocument, kTofkit };

[[nodiscard]] std::string_view to_string(ValidationRole role);
[[nodiscard]] std::string_view to_string(ValidationMethod method);

/// One row of a validation matrix.
struct ValidationRow {
  std::string id;          ///< unique, e.g. "paper.fig7.std"
  std::string document;    ///< "paper", "thesis", or the user's
  std::string figure;      ///< "Fig. 7", "Table 2", ... (rows of one figure are plotted together)
  std::string quantity;    ///< a registered quantity id (validation_quantities())
  std::string conditions;  ///< "key=value; key=value": the quantity's parameters
  std::map<std::string, std::string> parameters;  ///< the conditions, parsed
  double value = ranging::kNaN;                   ///< the document's value
  double band = ranging::kNaN;                    ///< half-width, absolute or relative
  bool band_relative = false;                     ///< band given as "X%" of |value|
  std::string band_reason;                        ///< why this band
  std::string unit;
  std::string preset;  ///< the device the row validates ("paper", "accurange", ...)
  ValidationRole role = ValidationRole::kHeldOut;
  ValidationMethod method = ValidationMethod::kDocument;
  std::string note;
  std::size_t line = 0;  ///< line of the matrix file (for messages), 0 when not from a file

  /// The band's absolute half-width in the value's unit.
  [[nodiscard]] double band_width() const;
};

/// A problem with a matrix row: names the line and the column.
class ValidationMatrixError : public std::invalid_argument {
 public:
  ValidationMatrixError(std::size_t line, std::string column, const std::string& message)
      : std::invalid_argument(message), line_(line), column_(std::move(column)) {}
  [[nodiscard]] std::size_t line() const noexcept { return line_; }
  [[nodiscard]] const std::string& column() const noexcept { return column_; }

 private:
  std::size_t line_;
  std::string column_;
};

/// A quantity a row may name.
struct QuantityInfo {
  std::string id;
  std::string unit;
  std::string description;
  std::vector<std::string> parameters;  ///< keys its conditions may give (others are refused)
  std::vector<std::string> required;    ///< keys its conditions must give
  bool tofkit_method = false;           ///< also computed with tofkit's own method
  /// Conditions the protocol fixes: a row may state them (for the reader), and
  /// a value other than the protocol's is refused.
  std::map<std::string, double> fixed{};
};

/// Every registered quantity, sorted by id.
[[nodiscard]] const std::vector<QuantityInfo>& validation_quantities();

/// Checks rows against the registry: unique ids, known quantity, accepted and
/// required condition keys, a method the quantity has. Throws
/// ValidationMatrixError naming the row's line and column.
void check_validation_rows(std::span<const ValidationRow> rows);

/// A point of a figure's curve: the twin's value at an abscissa (plots).
struct CurvePoint {
  double x = ranging::kNaN, y = ranging::kNaN;
};

struct ValidationOutcome {
  ValidationRow row;
  bool run = false;  ///< false: its preset was not selected (--preset/--config) or not in --only
  double twin = ranging::kNaN;
  bool in_band = false;
  bool outside_twice = false;  ///< |twin - value| > 2 band (or no value)
  std::string error;           ///< why the twin has no value (an experiment refused), else empty
  [[nodiscard]] bool counted() const { return run && row.method == ValidationMethod::kDocument; }
};

struct ValidationSummary {
  std::size_t rows = 0;  ///< counted: run, document method
  std::size_t in_band = 0;
  std::size_t outside_twice = 0;
  std::size_t held_out = 0, held_out_in_band = 0;
  std::size_t calibration = 0, calibration_in_band = 0;
  std::size_t tofkit_rows = 0, tofkit_in_band = 0;  ///< method = tofkit (not counted above)
  std::size_t not_run = 0;
  [[nodiscard]] double in_band_share() const;  ///< NaN without counted rows
  [[nodiscard]] double held_out_in_band_share() const;
  [[nodiscard]] double calibration_in_band_share() const;
};

struct ValidationResult {
  std::vector<ValidationOutcome> rows;  ///< in matrix order
  ValidationSummary summary;
  std::vector<std::string> devices;  ///< name of each device run
  /// The table (id / figure / document / twin / band / in band) and the summary, as text.
  [[nodiscard]] std::string table() const;
  [[nodiscard]] std::string summary_text() const;
};

/// The summary of outcomes (those of one preset when `preset` is not empty).
[[nodiscard]] ValidationSummary summarize_validation(std::span<const ValidationOutcome> outcomes,
                                                     std::string_view preset = {});

/// The device a preset name stands for, or nullopt when rows of that preset
/// are not to be run. Throwing refuses the run (e.g. an unknown preset).
using DeviceForPreset =
    std::function<std::optional<device::DeviceConfig>(const std::string& preset)>;

struct ValidationOptions {
  std::uint64_t seed = 2022;
  std::string only;  ///< run only rows whose id starts with this (empty: all)
  /// Called with a stage name and the share done (0..1).
  std::function<void(std::string_view stage, double done)> progress;
};

/// Runs every selected row (check_validation_rows first). Each experiment is
/// run at most once per device and seed. An experiment that throws leaves its
/// rows without a twin value (outcome.error says why), it does not stop the run.
[[nodiscard]] ValidationResult run_validation(std::span<const ValidationRow> rows,
                                              const DeviceForPreset& device_for_preset,
                                              const ValidationOptions& options = {});

/// Parses "key=value; key=value" (whitespace trimmed, values non-empty, keys
/// unique). Throws std::invalid_argument naming the bad part.
[[nodiscard]] std::map<std::string, std::string> parse_conditions(std::string_view text);

/// The abscissa a figure's plot puts the row at: the first numeric condition
/// in the order the quantity lists its parameters, else NaN.
[[nodiscard]] double plot_abscissa(const ValidationRow& row, std::string* name = nullptr);

}  // namespace tofkit::experiments
