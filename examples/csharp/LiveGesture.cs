// P/Invoke declarations of the LiveGesture C library (bindings/c/include/livegesture.h; docs/c.md).
// For Unity: put liblivegesture_c.so / .dylib / .dll into Assets/Plugins and this file into Assets.
using System;
using System.Runtime.InteropServices;

public static class LiveGesture
{
    const string Lib = "livegesture_c";
    public const int PoseDim = 165, TransDim = 3, ExprDim = 100, Fps = 30;
    // The face channel (docs/face.md): one LgFace is ArkitDim weights then VisemeDim probabilities, floats
    // with no padding, so a float[] of FaceDim per frame is its layout.
    public const int ArkitDim = 52, VisemeDim = 15, FaceDim = ArkitDim + VisemeDim;
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
    [DllImport(Lib)] public static extern int lg_stream_read_face(IntPtr stream, UIntPtr maxFrames, float[] poses, float[] trans, float[] expressions, ulong[] index, float[] face, out UIntPtr got);
    [DllImport(Lib)] public static extern int lg_model_has_face(IntPtr model);
    [DllImport(Lib, EntryPoint = "lg_arkit_name")] static extern IntPtr lg_arkit_name_ptr(UIntPtr i);
    [DllImport(Lib, EntryPoint = "lg_viseme_name")] static extern IntPtr lg_viseme_name_ptr(UIntPtr i);
    [DllImport(Lib)] public static extern int lg_stream_reset(IntPtr stream);
    [DllImport(Lib)] public static extern void lg_stream_free(IntPtr stream);
    [DllImport(Lib, EntryPoint = "lg_last_error")] static extern IntPtr lg_last_error_ptr();

    /// The ARKit name of face weight i ("jawOpen"...), null past the end.
    public static string ArkitName(int i) => Marshal.PtrToStringUTF8(lg_arkit_name_ptr((UIntPtr)i));
    /// The viseme name of face probability i ("aa"...), null past the end.
    public static string VisemeName(int i) => Marshal.PtrToStringUTF8(lg_viseme_name_ptr((UIntPtr)i));

    /// The message of the last failed call on this thread.
    public static string LastError() => Marshal.PtrToStringUTF8(lg_last_error_ptr());
}
