#pragma once
/// \file Writing output files: all of a command's outputs or none.
///
/// Every output file goes through write_file_atomically (or a writer built on
/// it: write_raw_csv, save_pipeline, write_plot, ...). The content goes to a
/// hidden temporary file in the target's directory (".NAME.tmp.PID.N"), which
/// is renamed over the target once complete. A failure (an exception from the
/// writer, a full disk) leaves no temporary behind and an existing target
/// untouched.
///
/// While an OutputTransaction is open (the `tofkit` CLI opens one around every
/// command, in main), completed temporaries are *staged*: they are renamed over
/// their targets only by commit(), all together, once the command has
/// succeeded. If the command throws, the transaction's destructor removes every
/// staged temporary and every directory it created, so a failing command
/// leaves the file system as it found it. New commands get this for free by
/// writing through these functions; they must not open output streams
/// themselves.
///
/// Refused with std::runtime_error naming the path, before anything is written:
/// - a target that exists and is not a regular file (a directory, a device
///   node such as /dev/null, a FIFO, a socket or a symbolic link: the rename
///   would replace the node itself);
/// - a target that is the same file (device and inode) as one the command
///   read as input (see note_input; the io readers call it), e.g.
///   `--out` equal to `--in` under another name;
/// - the same target twice in one transaction;
/// - a directory that does not exist.
///
/// SIGINT and SIGTERM remove every temporary of this process (staged or being
/// written) and the directories the open transaction created (those left
/// empty), and then terminate as the signal would have.

#include <cstdint>
#include <filesystem>
#include <functional>
#include <ostream>
#include <string>
#include <string_view>

namespace tofkit::io {

/// Write `path` through `write`, atomically (staged if a transaction is open).
/// Throws std::runtime_error naming the path on a refused target or a failed
/// write; rethrows whatever `write` throws, after removing the temporary file.
void write_file_atomically(const std::filesystem::path& path,
                           const std::function<void(std::ostream&)>& write);

/// Write `contents` to `path`, atomically.
void write_file_atomically(const std::filesystem::path& path, std::string_view contents);

/// Replace `path` with `contents` now, atomically, whether or not a transaction
/// is open: for a file that outlives the command that makes it (a calibration
/// cache entry). Its temporary is removed on failure and on SIGINT / SIGTERM,
/// as an output's is. Throws std::runtime_error naming the path on failure.
void replace_file_now(const std::filesystem::path& path, std::string_view contents);

/// The outputs of one command, committed together. At most one is open at a
/// time per process (a second throws std::logic_error).
class OutputTransaction {
 public:
  OutputTransaction();
  OutputTransaction(const OutputTransaction&) = delete;
  OutputTransaction& operator=(const OutputTransaction&) = delete;
  /// Not committed: removes every staged temporary and created directory.
  ~OutputTransaction();

  /// Renames every staged file over its target, in the order written. Throws
  /// std::runtime_error naming the file if a rename fails (the files not yet
  /// renamed are removed).
  void commit();

  /// Number of files staged so far.
  [[nodiscard]] std::size_t staged() const;
};

/// Is an OutputTransaction open?
[[nodiscard]] bool output_transaction_open();

/// Remember that `path` is an input of the command whose transaction is open:
/// writing over the same file (by device and inode, whatever its name) is
/// refused until the transaction ends. Readers call it; without an open
/// transaction it does nothing.
void note_input(const std::filesystem::path& path);

/// Create `path` and any missing parents (like create_directories); inside a
/// transaction, the directories created are removed again on rollback.
/// Throws std::runtime_error naming the path if it exists and is not a
/// directory or cannot be created.
void create_output_directories(const std::filesystem::path& path);

/// Hand a file that was written next to `target` (same directory, by another
/// program, e.g. gnuplot) to the output mechanism: renamed over `target` now,
/// or at commit when a transaction is open (removed on rollback).
void adopt_written_file(const std::filesystem::path& written, const std::filesystem::path& target);

/// The path where `target`'s content currently is: the staged temporary if
/// the open transaction holds one for it, else `target` itself.
[[nodiscard]] std::filesystem::path staged_path(const std::filesystem::path& target);

}  // namespace tofkit::io

namespace tofkit::io {

/// An output file written in pieces (a streaming command's appended blocks),
/// through the same mechanism as write_file_atomically: the target is checked
/// when the object is made, the content goes to a hidden temporary beside it
/// (removed on SIGINT / SIGTERM, on an exception, or when the object dies
/// uncommitted), and commit() stages it with the open transaction (or renames
/// it over the target when none is open). Not thread-safe: one writer.
class StreamingOutput {
 public:
  /// Throws std::runtime_error naming `target` if it is refused (see above).
  explicit StreamingOutput(std::filesystem::path target);
  StreamingOutput(const StreamingOutput&) = delete;
  StreamingOutput& operator=(const StreamingOutput&) = delete;
  StreamingOutput(StreamingOutput&&) noexcept;
  StreamingOutput& operator=(StreamingOutput&&) noexcept;
  ~StreamingOutput();

  /// Appends `bytes` at the end (buffered). Throws naming the target on a failed write.
  void append(std::string_view bytes);
  /// Overwrites bytes already written at `offset` (a header finished at the end).
  void write_at(std::uint64_t offset, std::string_view bytes);
  /// Appends `length` bytes of `from` (a scratch or another output), starting at `offset`.
  void append_from(int from_fd, std::uint64_t offset, std::uint64_t length);
  /// Bytes written so far.
  [[nodiscard]] std::uint64_t size() const { return size_; }
  [[nodiscard]] const std::filesystem::path& target() const { return target_; }
  /// Flushes, closes and stages (or renames) the file. Throws naming the target.
  void commit();

 private:
  void flush();
  std::filesystem::path target_;
  std::filesystem::path temporary_;
  std::size_t slot_ = 0;
  int fd_ = -1;
  std::uint64_t size_ = 0;
  std::string buffer_;
};

/// A temporary working file of a command that is never an output (a block
/// store read back at the end): made beside `near` (a file in the output
/// directory, so it is on the output's file system), removed when the object
/// dies (it is unlinked as soon as it is opened: nothing of it outlives the
/// process, whatever ends it).
class ScratchFile {
 public:
  explicit ScratchFile(const std::filesystem::path& near);
  ScratchFile(const ScratchFile&) = delete;
  ScratchFile& operator=(const ScratchFile&) = delete;
  ~ScratchFile();
  void append(std::string_view bytes);
  /// Reads `length` bytes at `offset` into `out` (flushing what is buffered first).
  void read(std::uint64_t offset, std::size_t length, void* out);
  [[nodiscard]] std::uint64_t size() const { return size_; }
  /// The file descriptor, flushed (for StreamingOutput::append_from).
  [[nodiscard]] int fd();

 private:
  void flush();
  std::filesystem::path path_;
  int fd_ = -1;
  std::uint64_t size_ = 0;
  std::string buffer_;
};

}  // namespace tofkit::io
