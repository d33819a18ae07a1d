// The C example's job from C# (examples/c/generate.c): poses of a WAV file as little-endian float32,
// frames x 165, on stdout. Test of docs/c.md's P/Invoke declarations with Debian's mono:
//   mcs -out:target/csharp/generate.exe examples/csharp/*.cs
//   LD_LIBRARY_PATH=target/release mono target/csharp/generate.exe BUNDLE IN.wav SEED [push|face] > out.f32
// With "push", the WAV's 16-bit mono samples are pushed in chunks of 1600 (lg_stream_push_i16) instead
// of lg_stream_generate_wav: the same frames. With "face", the output is the face channel instead of the
// poses (lg_stream_read_face: frames x (52 ARKit weights, 15 viseme probabilities)), after one line per
// ARKit and viseme name on stderr; a bundle without the face channel fails.
using System;
using System.IO;

static class Generate
{
    static int Fail(string what)
    {
        Console.Error.WriteLine("generate.exe: " + what + ": " + LiveGesture.LastError());
        return 2;
    }

    static int Main(string[] args)
    {
        if (args.Length < 3) { Console.Error.WriteLine("usage: generate.exe BUNDLE IN.wav SEED [push|face]"); return 2; }
        string mode = args.Length > 3 ? args[3] : "";
        if (LiveGesture.lg_model_load(args[0], "tract", out IntPtr model) != LiveGesture.Ok) return Fail("loading the bundle");
        bool face = mode == "face";
        if (face)
        {
            if (LiveGesture.lg_model_has_face(model) == 0) { Console.Error.WriteLine("generate.exe: " + args[0] + ": the bundle has no face channel"); return 2; }
            for (int i = 0; LiveGesture.ArkitName(i) != null; i++) Console.Error.WriteLine("arkit " + LiveGesture.ArkitName(i));
            for (int i = 0; LiveGesture.VisemeName(i) != null; i++) Console.Error.WriteLine("viseme " + LiveGesture.VisemeName(i));
        }
        var opts = LiveGesture.lg_stream_options_default();
        opts.seed = ulong.Parse(args[2]);
        if (LiveGesture.lg_stream_new(model, ref opts, out IntPtr stream) != LiveGesture.Ok) return Fail("creating a stream");
        var stdout = Console.OpenStandardOutput();
        int dim = face ? LiveGesture.FaceDim : LiveGesture.PoseDim;
        var values = new float[64 * dim];
        var bytes = new byte[values.Length * 4];
        var frames = new MemoryStream();
        Action drain = () => {
            UIntPtr got;
            do {
                int status = face
                    ? LiveGesture.lg_stream_read_face(stream, (UIntPtr)64, null, null, null, null, values, out got)
                    : LiveGesture.lg_stream_read(stream, (UIntPtr)64, values, null, null, null, out got);
                if (status != LiveGesture.Ok) throw new Exception(LiveGesture.LastError());
                Buffer.BlockCopy(values, 0, bytes, 0, (int)got * dim * 4);
                frames.Write(bytes, 0, (int)got * dim * 4);
            } while ((ulong)got > 0);
        };
        UIntPtr ready;
        if (mode == "push")
        {
            // a 16-bit mono PCM WAV with a 44-byte header, as the test writes it
            var wav = File.ReadAllBytes(args[1]);
            uint rate = BitConverter.ToUInt32(wav, 24);
            var pcm = new short[(wav.Length - 44) / 2];
            Buffer.BlockCopy(wav, 44, pcm, 0, pcm.Length * 2);
            for (int i = 0; i < pcm.Length; i += 1600)
            {
                var chunk = new short[Math.Min(1600, pcm.Length - i)];
                Array.Copy(pcm, i, chunk, 0, chunk.Length);
                if (LiveGesture.lg_stream_push_i16(stream, chunk, (UIntPtr)chunk.Length, rate, out ready) != LiveGesture.Ok) return Fail("pushing audio");
                drain();
            }
            if (LiveGesture.lg_stream_finish(stream, out ready) != LiveGesture.Ok) return Fail("finishing");
        }
        else if (LiveGesture.lg_stream_generate_wav(stream, args[1], out ready) != LiveGesture.Ok) return Fail("generating");
        drain();
        frames.WriteTo(stdout);
        stdout.Flush();
        LiveGesture.lg_stream_free(stream);
        LiveGesture.lg_model_free(model);
        return 0;
    }
}
