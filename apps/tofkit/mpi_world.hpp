#pragma once
/// \file Open MPI under `mpirun -np N tofkit scan|sweep ...` (or srun): the
/// ranks make a job's chunks as they ask for them and rank 0 writes the one output
/// set, the bytes of the one-process run. Built without MPI (no
/// find_package(MPI)), or run without a launcher, every command runs as one
/// process. A rank that fails exits without finalizing MPI, so the launcher
/// ends the job (rank 0, terminated, removes its staged files: no output).

#include <cstddef>
#include <functional>
#include <string>
#include <string_view>

namespace tofkit::app {

struct MpiWorld {
  int rank = 0, size = 1;
};

/// The world: under a launcher and built with MPI, MPI is initialized on the
/// first call; else {0, 1}.
[[nodiscard]] MpiWorld mpi_world();

/// The command succeeded on this rank: MPI is finalized at exit (after the
/// outputs are committed).
void mpi_done();

/// Chunks 0 .. chunks - 1, each made (`make(chunk, bytes)`, which appends
/// the chunk's bytes to `bytes`) by whichever rank asks for work next (rank 0
/// too), and rank 0 hands every chunk's bytes to `take` in chunk order
/// (memory: at most 2 x size chunks held by rank 0, one or two per other
/// rank). The chunks' buffers are reused (a fresh multi-megabyte buffer a
/// chunk cost both ranks its page faults).
void mpi_ordered_chunks(std::size_t chunks,
                        const std::function<void(std::size_t, std::string&)>& make,
                        const std::function<void(std::size_t, std::string_view)>& take);
/// Advances this rank's chunk on its way to rank 0 (call it now and then
/// while making the next one).
void mpi_progress();

/// Rank 0's `bytes` on every rank.
void mpi_broadcast(std::string& bytes);

}  // namespace tofkit::app
