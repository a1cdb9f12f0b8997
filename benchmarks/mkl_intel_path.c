/* MKL (torch's BLAS on x86) asks this whether it runs on an Intel CPU and, where not, takes other kernels than on
 * one. Preloaded (LD_PRELOAD) on an AMD CPU it answers yes, so that MKL takes its Intel AVX2 kernels there too and,
 * with the benchmarks' AVX2 pin, trains the same weights bit for bit as an Intel machine (kernel_reproducibility.md).
 * Built by benchmarks/_common.py: mkl_intel_path(). */
int mkl_serv_intel_cpu_true(void) { return 1; }
