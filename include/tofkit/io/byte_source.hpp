#pragma once
/// \file Byte streams of a device link: reading a serial port, a pseudo-
/// terminal, a capture file or stdin in chunks as they arrive, and creating a
/// pseudo-terminal for an emulated device to write to. POSIX only.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>

struct termios;

namespace tofkit::io {

/// Puts a terminal in raw mode (no echo, no line editing, no CR/LF
/// translation, 8 data bits, no parity, 1 stop bit) and, when baud > 0, sets
/// its speed. Throws std::runtime_error naming `name` (a baud rate termios
/// does not offer, a failing tcsetattr).
void configure_raw_terminal(int fd, int baud, const std::string& name);

/// A readable byte stream: "-" is stdin; a terminal (serial port, pty) is put
/// in raw mode at --baud (stdin keeps its signal keys: Ctrl-C is SIGINT) and
/// given back its settings when the ByteSource goes; anything else is read as
/// a file or pipe.
class ByteSource {
 public:
  /// Throws std::runtime_error naming the path (missing, unreadable, --baud
  /// given for something that is not a terminal).
  ByteSource(const std::string& path, int baud);
  ~ByteSource();
  ByteSource(const ByteSource&) = delete;
  ByteSource& operator=(const ByteSource&) = delete;

  enum class Status { kData, kTimeout, kEnd };
  /// Waits up to timeout_ms for bytes; `got` is how many were read into `buffer`.
  /// kEnd at end of file, or when the other side of a pty has closed.
  Status read(std::span<std::uint8_t> buffer, int timeout_ms, std::size_t& got);

  [[nodiscard]] bool is_terminal() const { return terminal_; }
  [[nodiscard]] int fd() const { return fd_; }

 private:
  void restore_terminal() noexcept;

  std::string path_;
  int fd_ = -1;
  bool owned_ = false;
  bool terminal_ = false;
  std::unique_ptr<termios> saved_;  // a terminal's settings before raw mode
};

/// A new pseudo-terminal pair in raw mode: the emulator writes to the master,
/// a host program opens slave_path() as if it were a serial port.
class PseudoTerminal {
 public:
  PseudoTerminal();  ///< throws std::runtime_error
  ~PseudoTerminal();
  PseudoTerminal(const PseudoTerminal&) = delete;
  PseudoTerminal& operator=(const PseudoTerminal&) = delete;

  [[nodiscard]] const std::string& slave_path() const { return slave_path_; }
  /// Waits until a reader has taken every byte written (up to timeout_ms);
  /// returns the bytes still unread. Closing the master earlier would hang up
  /// the line and could discard them.
  std::size_t wait_drained(int timeout_ms) const;
  [[nodiscard]] int master_fd() const { return master_; }
  /// Waits until a reader opens the slave (the line is up), then `settle_ms`
  /// more for it to set the line up: a reader such as pyserial flushes its
  /// input queue on open, and bytes written before would be lost. Returns
  /// false when `stop` became true first (checked every 10 ms).
  bool wait_for_reader(const std::atomic<bool>& stop, int settle_ms);
  /// After wait_drained: keeps the line up until the reader closes it, at
  /// most `linger_ms`, so a read in progress (pyserial's read(n) waits for n
  /// bytes or its timeout) returns its bytes instead of failing on a hang-up.
  void linger(const std::atomic<bool>& stop, int linger_ms);

 private:
  int master_ = -1;
  int slave_ = -1;  // held open so the raw settings stay while no reader is attached
  std::string slave_path_;
};

/// Writes all of `bytes` to fd (retrying short writes and EINTR); throws
/// std::runtime_error naming `name` on failure (a closed reader: EPIPE / EIO)
/// or when fd takes no byte for timeout_ms (negative: wait for ever).
void write_all(int fd, std::span<const std::uint8_t> bytes, const std::string& name,
               int timeout_ms = -1);

}  // namespace tofkit::io
