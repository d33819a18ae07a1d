/* ProcessPrng for wine < 9 (Debian 12 ships 8.0): Windows 10+ has it in bcryptprimitives.dll and Rust's
   standard library (1.78+) imports it for its random seeds; this forwards to advapi32's RtlGenRandom. */
#include <windows.h>
#define SystemFunction036 NTAPI SystemFunction036
#include <ntsecapi.h>
#undef SystemFunction036
__declspec(dllexport) BOOL WINAPI ProcessPrng(PBYTE data, SIZE_T len) {
  while (len > 0) {
    ULONG n = len > 0x40000000 ? 0x40000000 : (ULONG)len;
    if (!RtlGenRandom(data, n)) return FALSE;
    data += n; len -= n;
  }
  return TRUE;
}
