#include "mpi_world.hpp"

#include <unistd.h>

#include <cstdlib>
#include <stdexcept>

#if defined(TOFKIT_HAVE_MPI)
#include <mpi.h>
#endif

namespace tofkit::app {
namespace {

// Started by mpirun (Open MPI) or srun (Slurm's PMI/PMIx)?
bool under_launcher() {
  for (const char* name : {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"}) {
    if (std::getenv(name) != nullptr) return true;
  }
  return false;
}

bool g_done = false;

}  // namespace

#if defined(TOFKIT_HAVE_MPI)

namespace {

void finalize_at_exit() {
  int finalized = 0;
  MPI_Finalized(&finalized);
  // Only after success: a rank that failed must not wait for its peers in
  // MPI_Finalize; exiting without it makes the launcher end the job.
  if (g_done && !finalized) MPI_Finalize();
}

void check(int code, const char* what) {
  if (code != MPI_SUCCESS) throw std::runtime_error(std::string("MPI: ") + what + " failed");
}

constexpr int kChunkTag = 33;

// Waiting without spinning: a rank that waits gives its core to the others
// (MPI's blocking calls poll at full speed, which on a shared or
// oversubscribed node slows the rank being waited for).
void wait_politely(MPI_Request& request) {
  for (int done = 0;;) {
    check(MPI_Test(&request, &done, MPI_STATUS_IGNORE), "MPI_Test");
    if (done) return;
    ::usleep(100);
  }
}

// The send on its way (ranks other than 0): advanced by mpi_progress while
// the next chunk is made (a large message moves only while both sides are in
// MPI calls when the transport cannot read the sender's memory directly).
MPI_Request g_pending = MPI_REQUEST_NULL;

// Round-robin: chunk c is rank c % size's. (Giving rank 0, which also
// writes, fewer chunks was slower: writing costs far less than measuring.)
int owner(std::size_t chunk, int size) {
  return static_cast<int>(chunk % static_cast<std::size_t>(size));
}

}  // namespace

MpiWorld mpi_world() {
  static const MpiWorld world = [] {
    MpiWorld w;
    if (!under_launcher()) return w;
    int provided = 0;
    check(MPI_Init_thread(nullptr, nullptr, MPI_THREAD_FUNNELED, &provided), "MPI_Init_thread");
    std::atexit(finalize_at_exit);
    MPI_Comm_rank(MPI_COMM_WORLD, &w.rank);
    MPI_Comm_size(MPI_COMM_WORLD, &w.size);
    return w;
  }();
  return world;
}

void mpi_done() {
  g_done = true;
}

void mpi_ordered_chunks(std::size_t chunks, const std::function<std::string(std::size_t)>& make,
                        const std::function<void(std::size_t, std::string_view)>& take) {
  const MpiWorld w = mpi_world();
  if (w.rank == 0) {
    std::string received;
    for (std::size_t c = 0; c < chunks; ++c) {
      const int from = owner(c, w.size);
      if (from == 0) {
        const std::string bytes = make(c);
        take(c, bytes);
        continue;
      }
      MPI_Status status;
      for (int arrived = 0;;) {
        check(MPI_Iprobe(from, kChunkTag, MPI_COMM_WORLD, &arrived, &status), "MPI_Iprobe");
        if (arrived) break;
        ::usleep(100);
      }
      int count = 0;
      MPI_Get_count(&status, MPI_BYTE, &count);
      received.resize(static_cast<std::size_t>(count));
      check(MPI_Recv(received.data(), count, MPI_BYTE, from, kChunkTag, MPI_COMM_WORLD,
                     MPI_STATUS_IGNORE),
            "MPI_Recv");
      take(c, received);
    }
    return;
  }
  // The other ranks: make the next chunk while the last one is on its way.
  std::string sending;
  MPI_Request& request = g_pending;
  for (std::size_t c = 0; c < chunks; ++c) {
    if (owner(c, w.size) != w.rank) continue;
    std::string bytes = make(c);
    wait_politely(request);
    sending = std::move(bytes);
    check(MPI_Isend(sending.data(), static_cast<int>(sending.size()), MPI_BYTE, 0, kChunkTag,
                    MPI_COMM_WORLD, &request),
          "MPI_Isend");
  }
  wait_politely(request);
}

void mpi_progress() {
  if (g_pending == MPI_REQUEST_NULL) return;
  int done = 0;
  MPI_Test(&g_pending, &done, MPI_STATUS_IGNORE);
}

void mpi_broadcast(std::string& bytes) {
  unsigned long long size = bytes.size();
  check(MPI_Bcast(&size, 1, MPI_UNSIGNED_LONG_LONG, 0, MPI_COMM_WORLD), "MPI_Bcast");
  bytes.resize(size);
  check(MPI_Bcast(bytes.data(), static_cast<int>(size), MPI_BYTE, 0, MPI_COMM_WORLD), "MPI_Bcast");
}

#else

MpiWorld mpi_world() {
  const char* size = std::getenv("OMPI_COMM_WORLD_SIZE");
  if (size == nullptr) size = std::getenv("PMI_SIZE");
  if (under_launcher() && size != nullptr && std::string(size) != "1") {
    throw std::runtime_error(
        "started by mpirun, but this tofkit was built without MPI (install libopenmpi-dev and "
        "rebuild): each rank would write the whole output");
  }
  return {};
}

void mpi_done() {
  g_done = true;
}

void mpi_ordered_chunks(std::size_t chunks, const std::function<std::string(std::size_t)>& make,
                        const std::function<void(std::size_t, std::string_view)>& take) {
  for (std::size_t c = 0; c < chunks; ++c) take(c, make(c));
}

void mpi_broadcast(std::string&) {}

void mpi_progress() {}

#endif

}  // namespace tofkit::app
