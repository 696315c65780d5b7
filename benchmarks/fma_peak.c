/* The CPU's FP32 fused multiply-add peak, measured: the denominator of "fraction of peak"
 * in benchmarks/bench_fused_mlp.py.
 *
 * Each thread runs 12 independent FMA chains on the widest vectors the compiler targets
 * (AVX-512 when built with -march=native on a CPU that has it, else AVX2): 12 chains hide
 * the 4-cycle FMA latency on two FMA ports, so the loop runs at the FMA units' throughput.
 * Prints one line per run: vector width, threads, GFLOP/s of wall time, and GFLOP per
 * second of CPU time summed over the threads (the per-core rate, which does not depend on
 * what else the machine runs).
 *
 * Build and run: cc -O2 -march=native -pthread benchmarks/fma_peak.c -o /tmp/fma_peak &&
 *                /tmp/fma_peak [threads] [iterations]
 */
#include <immintrin.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#define CHAINS 12

#ifdef __AVX512F__
#define LANES 16
typedef __m512 vec;
#define SET1 _mm512_set1_ps
#define FMA _mm512_fmadd_ps
#define ADD _mm512_add_ps
#define STORE _mm512_storeu_ps
#else
#define LANES 8
typedef __m256 vec;
#define SET1 _mm256_set1_ps
#define FMA _mm256_fmadd_ps
#define ADD _mm256_add_ps
#define STORE _mm256_storeu_ps
#endif

static long iterations = 100000000L;
static float sink[64][LANES];
static double cpu_seconds[64];

static double now(clockid_t clock) {
    struct timespec t;
    clock_gettime(clock, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

static void *run(void *arg) {
    long id = (long) arg;
    double start = now(CLOCK_THREAD_CPUTIME_ID);
    vec a[CHAINS], m = SET1(0.999999f), c = SET1(1e-7f);
    for (int i = 0; i < CHAINS; ++i)
        a[i] = SET1((float) (i + id));
    for (long it = 0; it < iterations; ++it) {
#pragma GCC unroll 12
        for (int i = 0; i < CHAINS; ++i)
            a[i] = FMA(a[i], m, c);
    }
    vec s = a[0];
    for (int i = 1; i < CHAINS; ++i)
        s = ADD(s, a[i]);
    STORE(sink[id], s);
    cpu_seconds[id] = now(CLOCK_THREAD_CPUTIME_ID) - start;
    return NULL;
}

int main(int argc, char **argv) {
    int threads = argc > 1 ? atoi(argv[1]) : 1;
    if (argc > 2)
        iterations = atol(argv[2]);
    if (threads < 1 || threads > 64)
        return 1;
    pthread_t th[64];
    double start = now(CLOCK_MONOTONIC);
    for (long i = 0; i < threads; ++i)
        pthread_create(&th[i], NULL, run, (void *) i);
    double cpu = 0.0;
    for (int i = 0; i < threads; ++i) {
        pthread_join(th[i], NULL);
        cpu += cpu_seconds[i];
    }
    double wall = now(CLOCK_MONOTONIC) - start;
    double flops = 2.0 * LANES * CHAINS * (double) iterations * threads;
    printf("lanes %d threads %d wall_gflops %.2f gflops_per_cpu_second %.2f\n", LANES, threads,
           flops / wall * 1e-9, flops / cpu * 1e-9);
    return 0;
}
