// The C example's job from C# (examples/c/generate.c): poses of a WAV file as little-endian float32,
// frames x 165, on stdout. Test of docs/c.md's P/Invoke declarations with Debian's mono:
//   mcs -out:target/csharp/generate.exe examples/csharp/*.cs
//   LD_LIBRARY_PATH=target/release mono target/csharp/generate.exe BUNDLE IN.wav SEED [push] > poses.f32
// With "push", the WAV's 16-bit mono samples are pushed in chunks of 1600 (lg_stream_push_i16) instead
// of lg_stream_generate_wav: the same frames.
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
        if (args.Length < 3) { Console.Error.WriteLine("usage: generate.exe BUNDLE IN.wav SEED [push]"); return 2; }
        if (LiveGesture.lg_model_load(args[0], "tract", out IntPtr model) != LiveGesture.Ok) return Fail("loading the bundle");
        var opts = LiveGesture.lg_stream_options_default();
        opts.seed = ulong.Parse(args[2]);
        if (LiveGesture.lg_stream_new(model, ref opts, out IntPtr stream) != LiveGesture.Ok) return Fail("creating a stream");
        var stdout = Console.OpenStandardOutput();
        var poses = new float[64 * LiveGesture.PoseDim];
        var bytes = new byte[poses.Length * 4];
        var frames = new MemoryStream();
        Action drain = () => {
            UIntPtr got;
            do {
                if (LiveGesture.lg_stream_read(stream, (UIntPtr)64, poses, null, null, null, out got) != LiveGesture.Ok) throw new Exception(LiveGesture.LastError());
                Buffer.BlockCopy(poses, 0, bytes, 0, (int)got * LiveGesture.PoseDim * 4);
                frames.Write(bytes, 0, (int)got * LiveGesture.PoseDim * 4);
            } while ((ulong)got > 0);
        };
        UIntPtr ready;
        if (args.Length > 3 && args[3] == "push")
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
