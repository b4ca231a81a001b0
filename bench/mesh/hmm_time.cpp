// A timing driver for fogleman/hmm's triangulator (bench/mesh/compare.sh links it with hmm's
// own sources in bench/mesh/peers/hmm, never committed): loads the 16-bit PNG with hmm's
// Heightmap, runs Triangulator::Run(threshold) and extracts Points/Triangles RUNS times, and
// prints one line "WALL_MS CPU_MS" per run (thread CPU time: steady under machine load).
// Writes the last mesh to OUT.bin as u32 vertex count, u32 triangle count, u32 (x, y) per
// vertex (hmm's output frame: y = height - 1 - row, row 0 south) and u32 x 3 per triangle.
//
//   hmm_time DEM.png THRESHOLD RUNS OUT.bin
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <memory>
#include <vector>

#include "heightmap.h"
#include "triangulator.h"

static double cpu_ms() {
    timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return t.tv_sec * 1e3 + t.tv_nsec / 1e6;
}

int main(int argc, char **argv) {
    if (argc != 5) {
        std::fprintf(stderr, "usage: hmm_time DEM.png THRESHOLD RUNS OUT.bin\n");
        return 2;
    }
    const auto hm = std::make_shared<Heightmap>(argv[1]);
    if (hm->Width() * hm->Height() == 0) {
        std::fprintf(stderr, "%s: not a readable heightmap\n", argv[1]);
        return 1;
    }
    const float threshold = std::atof(argv[2]);
    const int runs = std::atoi(argv[3]);
    std::vector<glm::vec3> points;
    std::vector<glm::ivec3> triangles;
    for (int r = 0; r < runs; r++) {
        const auto w0 = std::chrono::steady_clock::now();
        const double c0 = cpu_ms();
        Triangulator tri(hm);
        tri.Run(threshold, 0, 0);
        points = tri.Points(1);
        triangles = tri.Triangles();
        const double c1 = cpu_ms();
        const std::chrono::duration<double, std::milli> wall = std::chrono::steady_clock::now() - w0;
        std::printf("%f %f\n", wall.count(), c1 - c0);
    }
    FILE *f = std::fopen(argv[4], "wb");
    if (!f) {
        std::perror(argv[4]);
        return 1;
    }
    const unsigned n[2] = {(unsigned)points.size(), (unsigned)triangles.size()};
    std::fwrite(n, 4, 2, f);
    for (const auto &p : points) {
        const unsigned xy[2] = {(unsigned)p.x, (unsigned)p.y};
        std::fwrite(xy, 4, 2, f);
    }
    for (const auto &t : triangles) {
        const unsigned v[3] = {(unsigned)t.x, (unsigned)t.y, (unsigned)t.z};
        std::fwrite(v, 4, 3, f);
    }
    std::fclose(f);
    return 0;
}
