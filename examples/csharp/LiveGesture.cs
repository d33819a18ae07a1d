// P/Invoke declarations of the LiveGesture C library (bindings/c/include/livegesture.h; docs/c.md).
// For Unity: put liblivegesture_c.so / .dylib / .dll into Assets/Plugins and this file into Assets.
using System;
using System.Runtime.InteropServices;

public static class LiveGesture
{
    const string Lib = "livegesture_c";
    public const int PoseDim = 165, TransDim = 3, ExprDim = 100, Fps = 30;
    public const int Ok = 0; // LG_STATUS_OK; NOT_FOUND 1, IO 2, INPUT 3, RUNTIME 4, PANIC 5

    [StructLayout(LayoutKind.Sequential)]
    public struct StreamOptions
    {
        public ulong seed;
        public double guidance, temperature;   // NaN: the bundle's default
        public long top_k, ddim_steps, jumps, window, overlap, blend_steps, speaker;   // -1: default
    }

    [DllImport(Lib)] public static extern int lg_model_load([MarshalAs(UnmanagedType.LPUTF8Str)] string bundleDir, [MarshalAs(UnmanagedType.LPUTF8Str)] string backend, out IntPtr model);
    [DllImport(Lib)] public static extern void lg_model_free(IntPtr model);
    [DllImport(Lib)] public static extern StreamOptions lg_stream_options_default();
    [DllImport(Lib)] public static extern int lg_stream_new(IntPtr model, ref StreamOptions opts, out IntPtr stream);
    [DllImport(Lib)] public static extern int lg_stream_push(IntPtr stream, float[] samples, UIntPtr n, uint sampleRate, out UIntPtr ready);
    [DllImport(Lib)] public static extern int lg_stream_push_i16(IntPtr stream, short[] samples, UIntPtr n, uint sampleRate, out UIntPtr ready);
    [DllImport(Lib)] public static extern int lg_stream_finish(IntPtr stream, out UIntPtr ready);
    [DllImport(Lib)] public static extern int lg_stream_generate_wav(IntPtr stream, [MarshalAs(UnmanagedType.LPUTF8Str)] string wavPath, out UIntPtr ready);
    [DllImport(Lib)] public static extern int lg_stream_read(IntPtr stream, UIntPtr maxFrames, float[] poses, float[] trans, float[] expressions, ulong[] index, out UIntPtr got);
    [DllImport(Lib)] public static extern int lg_stream_reset(IntPtr stream);
    [DllImport(Lib)] public static extern void lg_stream_free(IntPtr stream);
    [DllImport(Lib, EntryPoint = "lg_last_error")] static extern IntPtr lg_last_error_ptr();

    /// The message of the last failed call on this thread.
    public static string LastError() => Marshal.PtrToStringUTF8(lg_last_error_ptr());
}
